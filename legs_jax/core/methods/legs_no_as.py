"""LEGS(-AS): Thompson sampling over all K grasps, pruned by the LEGS rule
every n steps (the pose just grasped), with no refill."""

from typing import NamedTuple

import numpy as np

from legs_jax.core import reference as ref
from legs_jax.core.methods import _beta_twin as twin
from legs_jax.core.methods import _dense
from legs_jax.core.methods.base import (
    COUNT,
    PRIOR_RANGES,
    UNIT_OPEN,
    Card,
    Method,
    every_n_steps,
)


class LegsNoASHParams(NamedTuple):
    s: float = 1.0  # prior strength
    prior_offset: float = 1.0  # the +1
    delta: float = 0.05  # confidence of the pruning bounds
    gamma: float = 0.2  # global threshold
    n: int = 100  # pruning period (static)


class Reference(twin.BetaMethod):
    """LEGS(-AS): Thompson sampling over all K minus the removed grasps."""

    def _prune_set(self, s: int) -> np.ndarray:
        """[K] bool, the LEGS removal set of pose s
        (:func:`legs_jax.core.reference.legs_prune`)."""
        hp = self.hp
        args = (self.alpha[s], self.beta[s], self.attempted[s], self.cand[s])
        return ref.legs_prune(*args, hp["delta"], hp["gamma"])

    def after_step(self, t: int, s: int) -> None:
        if t % self.hp["n"] != 0:
            return
        removed = self._prune_set(s)
        self.cand[s] &= ~removed
        self.replacements += int(removed.sum())
        self.removal_log += [(t, s, int(g)) for g in np.flatnonzero(removed)]
        self._dirty[s] = True


METHOD = Method(
    name="legs_no_as",
    description="LEGS(-AS): all K grasps, LEGS pruning, no active set",
    **_dense.FUNCTIONS,
    init=lambda ctx, cfg: _dense.init(ctx, cfg, removable=True),
    prune=_dense.prune,
    prune_due=every_n_steps,
    hparams=LegsNoASHParams,
    ranges={**PRIOR_RANGES, "delta": UNIT_OPEN, "gamma": UNIT_OPEN, "n": COUNT},
    static=("n",),
    card=Card(
        bench_proxy="borges_2000",
        label="LEGS(-AS)",
        short_label="LEGS(-AS)",
        style=dict(color="#1f77b4", ls="-", lw=1.6),
        dense=True,
        reference=Reference,
    ),
)
