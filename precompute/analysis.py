"""Prior-only rows of Table I and other per-object statistics of a problem.

Gaps as the sweep computes them: Δ = Σ_s λ_s (p*_s − p[s, π(s)]) with p*_s the
best p of the trial's reservoir of pose s; by the rule a method declares
(``prior_only``): "greedy" (Dex-Net), π(s) = argmax q over the valid grasps
(ties: lowest index); "top" (the K100 upper bound), π(s) = argmax p over the 100
grasps of highest q.
A pose without valid grasps adds nothing. Per object, the mean over trials.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PAPER", "prior_only_gaps", "prior_only_rows", "top_by_prior"]

#: Table I of the paper: the gaps of the prior-only rows (in the order of
#: :func:`prior_only_rows`: greedy, then top) per set.
PAPER = {"dexnet_adv": (0.56, 0.08), "egad_eval": (0.59, 0.13)}


def prior_only_rows() -> dict[str, str]:
    """Table I's rows that the prior alone decides, from the methods' declarations:
    method -> its rule (``"greedy"`` or ``"top"``), in registry order."""
    from legs_jax.core import methods  # jax: kept out of precompute's start-up

    rows = {m: methods.get(m).card.prior_only for m in methods.names()}
    return {m: rule for m, rule in rows.items() if rule}


def top_by_prior(q: np.ndarray, valid: np.ndarray, k: int) -> np.ndarray:
    """[..., k] indices of the k valid grasps of highest q (ties: lower index),
    -1 where fewer than k are valid."""
    key = np.where(valid, q, -np.inf)
    order = np.argsort(-key, axis=-1, kind="stable")[..., :k]
    ok = np.take_along_axis(valid, order, axis=-1)
    return np.where(ok, order, -1)


def prior_only_gaps(
    landing: np.ndarray,  # [P]
    robustness: np.ndarray,  # [T, P, K]
    prior: np.ndarray,  # [T, P, K]
    valid: np.ndarray,  # [T, P, K]
    k: int = 100,
) -> dict[str, np.ndarray]:
    """Per-trial gaps [T] of the greedy row and the K-top upper bound (by rule:
    ``"greedy"``, ``"top"``), and the λ-weighted p* (``"p_star"``)."""
    p = np.where(valid, robustness, 0.0).astype(np.float64)
    p_star = p.max(axis=-1)  # [T, P]
    greedy = top_by_prior(prior, valid, 1)[..., 0]  # [T, P]
    p_greedy = np.where(
        greedy >= 0,
        np.take_along_axis(p, np.maximum(greedy, 0)[..., None], -1)[..., 0],
        0,
    )
    top = top_by_prior(prior, valid, k)  # [T, P, k]
    p_top = np.where(top >= 0, np.take_along_axis(p, np.maximum(top, 0), -1), 0.0)
    p_ub = p_top.max(axis=-1)
    lam = np.asarray(landing, np.float64)
    return {
        "greedy": ((p_star - p_greedy) * lam).sum(axis=-1),
        "top": ((p_star - p_ub) * lam).sum(axis=-1),
        "p_star": (p_star * lam).sum(axis=-1),
    }
