"""The NumPy twins of the Beta-posterior methods (:mod:`legs_jax.core.reference`
runs them): Thompson sampling on the Beta posterior, the constant rows
and BORGES. They read the prior's hyperparameters (:class:`BetaPrior`) here, with
the methods that declare them; the reference's loop reads none by name."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from legs_jax.core import reference as ref
from legs_jax.core.constants import Q_CLIP
from legs_jax.core.problem import Problem

__all__ = ["BetaMethod", "Borges", "Fixed"]


class BetaMethod(ref.ReferenceMethod):
    """Thompson sampling on the Beta posterior over ``cand``."""

    def __init__(self, problem: Problem, trial: int, hp: Mapping[str, Any]):
        super().__init__(problem, trial, hp)
        qc = np.clip(self.q, *Q_CLIP)
        off, s = hp["prior_offset"], hp["s"]
        # α = prior_offset + s·q + S, β = prior_offset + s·(1 − q) + F; S = F = 0.
        self.alpha = np.where(self.valid, off + s * qc, 1.0)  # [P, K]
        self.beta = np.where(self.valid, off + s * (1.0 - qc), 1.0)  # [P, K]

    def select(self, s: int, rng: np.random.Generator) -> int:
        idx = np.flatnonzero(self.cand[s])  # ascending grasp ids
        phi = rng.beta(self.alpha[s, idx], self.beta[s, idx])
        return int(idx[np.argmax(phi)])

    def update(self, s: int, a: int, r: bool) -> None:
        super().update(s, a, r)
        if r:
            self.alpha[s, a] += 1.0
        else:
            self.beta[s, a] += 1.0

    def _score(self) -> np.ndarray:
        return self.alpha / (self.alpha + self.beta)

    def _recommend_pose(self, s: int) -> int:
        idx = np.flatnonzero(self.cand[s])  # ascending grasp ids
        if idx.size == 0:
            return -1
        if self.visited[s]:  # argmax posterior mean
            a, b = self.alpha[s, idx], self.beta[s, idx]
            return int(idx[np.argmax(a / (a + b))])
        return int(idx[np.argmax(self.q[s, idx])])  # no data yet: argmax prior


class Fixed(BetaMethod):
    """A constant row: ``choice`` [P] in every pose; its Beta posterior over the
    candidates (all valid grasps, or the top ``top`` by q) serves the check."""

    def __init__(self, problem, trial, hp, choice: np.ndarray, top: int | None = None):
        super().__init__(problem, trial, hp)
        if top is not None:
            self.cand = ref.top_mask(self.q, self.valid, top)
        self.choice = np.asarray(choice)  # [P]

    def select(self, s: int, rng: np.random.Generator) -> int:
        return int(self.choice[s])

    def _recommend_pose(self, s: int) -> int:
        return int(self.choice[s])


class Borges(BetaMethod):
    """BORGES: Thompson sampling over a fixed candidate set (top-100 or all K)."""

    def __init__(self, problem, trial, hp, top: int | None):
        super().__init__(problem, trial, hp)
        if top is not None:
            self.cand = ref.top_mask(self.q, self.valid, top)
