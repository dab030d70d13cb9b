"""LEGS (Algorithm 1): Thompson sampling over an active set of k grasps per pose,
pruned every n steps by the LEGS rule and refilled from the reservoir in descending
q.

The active set of every pose is built at step 0 (it depends on nothing learned, so
this equals building it on the first visit). The pruning step of one pose is
:func:`legs_jax.core.methods._slots.prune_refill`, a pure function of the state;
:func:`legs_jax.core.methods.base.prune_mask` is the removal set alone and
:func:`legs_jax.core.methods.base.every_n_steps` LEGS's schedule of it.
"""

from typing import NamedTuple

import numpy as np

from legs_jax.core import reference as ref
from legs_jax.core.methods import _slots, legs_no_as
from legs_jax.core.methods.base import (
    COUNT,
    PRIOR_RANGES,
    UNIT_OPEN,
    Card,
    Method,
    check_prior,
    every_n_steps,
)
from legs_jax.errors import ConfigError

__all__ = ["METHOD", "LegsHParams"]


class LegsHParams(NamedTuple):
    s: float = 1.0  # prior strength
    prior_offset: float = 1.0  # the +1
    delta: float = 0.05  # confidence of the pruning bounds
    gamma: float = 0.2  # global threshold
    k: int = 100  # active-set size (static)
    n: int = 100  # pruning period (static)


RANGES = {
    **PRIOR_RANGES,
    "delta": UNIT_OPEN,
    "gamma": UNIT_OPEN,
    "k": COUNT,
    "n": COUNT,
}


def check(hp, num_grasps):
    check_prior(hp, num_grasps)
    if num_grasps is not None and np.any(hp["k"] > num_grasps):
        raise ConfigError(
            f"k = {int(np.max(hp['k']))} exceeds the K = {num_grasps} grasps per pose "
            "of the problems"
        )


class Reference(legs_no_as.Reference):
    """LEGS: Thompson sampling over an active set of k slots, pruned and refilled."""

    def __init__(self, problem, trial, hp):
        super().__init__(problem, trial, hp)
        P, k = self.q.shape[0], hp["k"]
        self.slots = np.full((P, k), -1)  # [P, k] grasp id per slot, -1 empty
        self.queue: list[np.ndarray] = []  # per pose: refill order (descending q)
        self.queue_next = np.zeros(P, int)  # per pose: next queue position
        for s in range(P):
            ranked = ref.rank_by_prior(self.q[s], self.valid[s])
            self.slots[s, : min(k, ranked.size)] = ranked[:k]
            self.queue.append(ranked[k:])
        self.cand = np.zeros_like(self.valid)
        for s in range(P):
            self.cand[s, self.slots[s][self.slots[s] >= 0]] = True

    def after_step(self, t: int, s: int) -> None:
        if t % self.hp["n"] != 0:
            return
        removed = self._prune_set(s)
        for j in range(self.slots.shape[1]):  # slot order
            g = self.slots[s, j]
            if g < 0 or not removed[g]:
                continue
            self.cand[s, g] = False
            self.replacements += 1
            self.removal_log.append((t, s, int(g)))
            if self.queue_next[s] < self.queue[s].size:
                new = self.queue[s][self.queue_next[s]]
                self.queue_next[s] += 1
                self.slots[s, j] = new
                self.cand[s, new] = True  # its posterior is still the prior
            else:
                self.slots[s, j] = -1
        self._dirty[s] = True

    def active_slots(self, k: int) -> np.ndarray:
        return np.where(self.visited[:, None], self.slots, -1)


METHOD = Method(
    name="legs",
    description="LEGS: active set of k grasps, pruned and refilled",
    **_slots.FUNCTIONS,
    init=lambda ctx, cfg: _slots.init(ctx, cfg, cfg.k, refill=True),
    prune=_slots.prune_refill,
    prune_due=every_n_steps,
    active_set=_slots.active_set,
    active_width=lambda cfg: cfg.k,
    hparams=LegsHParams,
    ranges=RANGES,
    static=("k", "n"),
    check=check,
    card=Card(
        bench=True,
        label="LEGS",
        short_label="LEGS",
        style=dict(color="#d62728", ls="-", lw=2.4),
        cost=lambda cfg: float(min(cfg.k, cfg.num_grasps)),
        reference=Reference,
    ),
)
