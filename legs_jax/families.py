"""Problem families with controlled properties, and the same features measured on
any problem (experiment ``regimes``: when does LEGS win?).

:func:`make_problem` builds an abstract bandit problem (no geometry) whose every
property the ``regimes`` map varies is set by one argument:

- the shape of the ground-truth distribution of p in each pose (``shape``, one of
  :data:`SHAPES`): a "body" Beta(a, b), from a hump in the middle (our real
  reservoirs: mode 0.2-0.5) to a mass near 0 (the paper's Fig. 3), mixed with a
  share ``excellent`` of excellent grasps, p ~ Beta(18, 1.5) (mean 0.92);
- the prior's quality: its C-index ``auc`` (:func:`concordance`), from 0.5 (q
  carries no information) to 1 (q orders the grasps as p does);
- the prior's calibration (``calibration``, one of :data:`CALIBRATIONS`): q has
  the histogram of p (``calibrated``), or is shifted in logit space, up
  (``optimistic``) or down (``pessimistic``, GQ-CNN on adversarial objects: near
  zero except at the most robust grasps); a shift changes no ranking, so it leaves
  the AUC as it is;
- the number of poses P and how the landing probabilities λ concentrate: λ_s ∝
  exp(−c·s), with c chosen so that the effective number of poses 1/Σλ² is
  ``effective_poses`` (1 ≤ it ≤ P; P gives the uniform λ);
- the horizon H is not a property of the problem: the map reads the gap curves.

A failed grasp drops the object again (every topple row is λ), so a pose gets
about λ_s·H attempts, as the issue's measurements assume.

:func:`features` measures, the same way on generated and real problems, what the
map is drawn over: the typical grasp relative to the best (mean p / p*), the
share and number of grasps within 0.05 of p*, the prior's C-index and
calibration bias, the effective number of poses and the attempts per active grasp.

Dimension letters: T trials, P poses, K grasps per pose.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import special

from legs_jax.core.problem import Problem, _no_geometry

__all__ = [
    "CALIBRATIONS",
    "EXCELLENT",
    "NEAR",
    "SHAPES",
    "concordance",
    "features",
    "landing",
    "make_problem",
    "mixture_cdf",
    "rho_for_auc",
]

# Body of the p distribution of a pose: Beta(a, b), from a hump to a mass near 0.
SHAPES: dict[str, tuple[float, float]] = {
    "hump": (4.0, 5.0),  # mode 0.43, like our reservoirs
    "skewed": (2.0, 5.0),  # mode 0.2
    "low": (1.0, 6.0),  # mode 0
    "bimodal": (0.4, 6.0),  # most grasps near 0 (the paper's Fig. 3)
}
# Excellent grasps: p ~ Beta(18, 1.5), mean 0.92.
EXCELLENT = (18.0, 1.5)
# Logit shifts of the prior.
CALIBRATIONS: dict[str, float] = {
    "optimistic": 1.5,
    "calibrated": 0.0,
    "pessimistic": -3.0,
}
# "Near the best": within this much of p*.
NEAR = 0.05


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise ValueError(msg)


def rho_for_auc(auc: float) -> float:
    """Correlation of the Gaussian copula whose C-index is ``auc``:
    C = 1/2 + arcsin(ρ)/π (Kendall's τ = 2 arcsin(ρ)/π of a bivariate normal)."""
    _check(0.5 <= auc <= 1.0, f"auc must lie in [0.5, 1], got {auc}")
    return math.sin(math.pi * (auc - 0.5))


def landing(num_poses: int, effective_poses: float) -> np.ndarray:
    """[P] λ_s ∝ exp(−c·s) with 1/Σλ² = ``effective_poses`` (bisection on c)."""
    P = num_poses
    _check(
        1.0 <= effective_poses <= P,
        f"effective_poses must lie in [1, {P}] for {P} poses, got {effective_poses}",
    )
    s = np.arange(P, dtype=np.float64)

    def lam(c: float) -> np.ndarray:
        w = np.exp(-c * s)
        return w / w.sum()

    if effective_poses >= P - 1e-9:
        return lam(0.0)
    lo, hi = 0.0, 50.0  # 1/Σλ² falls from P (c = 0) to about 1 (c = 50)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 1.0 / np.sum(lam(mid) ** 2) > effective_poses:
            lo = mid
        else:
            hi = mid
    return lam(0.5 * (lo + hi))


def mixture_cdf(x: np.ndarray, shape: str, excellent: float) -> np.ndarray:
    """CDF of p in a pose of the family (the known answer of the tests)."""
    from scipy import stats

    a, b = SHAPES[shape]
    return (1.0 - excellent) * stats.beta.cdf(x, a, b) + excellent * stats.beta.cdf(
        x, *EXCELLENT
    )


def make_problem(
    seed: int = 0,
    *,
    shape: str = "hump",
    excellent: float = 0.01,
    auc: float = 0.8,
    calibration: str = "calibrated",
    num_poses: int = 8,
    effective_poses: float = 4.0,
    num_grasps: int = 2000,
    num_trials: int = 5,
    name: str | None = None,
) -> Problem:
    """A problem of the family, deterministic in its arguments (module docstring).

    Args:
      seed: random seed; the same arguments give an identical problem.
      shape: body of the p distribution (:data:`SHAPES`).
      excellent: share of excellent grasps (p ~ Beta(18, 1.5)), in [0, 1].
      auc: the prior's C-index within a pose, in [0.5, 1].
      calibration: :data:`CALIBRATIONS` (logit shift of q).
      num_poses, effective_poses: P and 1/Σλ².
      num_grasps, num_trials: K and T.
      name: the problem's name (default ``family-<seed>``).
    """
    _check(shape in SHAPES, f"shape must be one of {', '.join(SHAPES)}, got {shape!r}")
    _check(
        calibration in CALIBRATIONS,
        f"calibration must be one of {', '.join(CALIBRATIONS)}, got {calibration!r}",
    )
    _check(0.0 <= excellent <= 1.0, f"excellent must lie in [0, 1], got {excellent}")
    _check(
        num_poses >= 1 and num_grasps >= 2 and num_trials >= 1,
        "num_poses, num_trials must be >= 1 and num_grasps >= 2",
    )
    rho = rho_for_auc(auc)
    lam = landing(num_poses, effective_poses)
    T, P, K = num_trials, num_poses, num_grasps
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x4E61]))

    a, b = SHAPES[shape]
    good = rng.random((T, P, K)) < excellent
    p = np.where(good, rng.beta(*EXCELLENT, size=(T, P, K)), rng.beta(a, b, (T, P, K)))

    # Gaussian copula: normal scores of p's ranks, mixed with independent noise.
    ranks = np.argsort(np.argsort(p, axis=-1, kind="stable"), axis=-1)
    z = special.ndtri((ranks + 0.5) / K)
    score = rho * z + math.sqrt(max(0.0, 1.0 - rho * rho)) * rng.normal(size=p.shape)
    # Calibrated: q has p's histogram in the pose (quantile of p at the score's level).
    u = special.ndtr(score)
    p_sorted = np.sort(p, axis=-1)
    pos = u * (K - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, K - 1)
    frac = pos - lo
    q = (1.0 - frac) * np.take_along_axis(p_sorted, lo, -1) + frac * np.take_along_axis(
        p_sorted, hi, -1
    )
    shift = CALIBRATIONS[calibration]
    if shift:
        qc = np.clip(q, 1e-6, 1 - 1e-6)
        q = special.expit(special.logit(qc) + shift)

    # Canonical values, so that the same arguments give the same bytes on every
    # processor: the transcendental functions above (NumPy's, SciPy's, libm's) may
    # round differently where they are vectorised differently, by an ulp or so;
    # p and q on the levels k / 2^20 (exact in float32) and λ on 2^32 integer
    # levels absorb that (an ulp crosses a level boundary with probability about
    # 1e-9 per value).
    f32 = np.float32
    p = _levels(p, 2**20)
    q = _levels(q, 2**20)
    lam_int = np.rint(lam * 2.0**32)
    lam = lam_int / lam_int.sum()
    return Problem(
        name=name if name is not None else f"family-{seed}",
        landing=lam.astype(f32),
        topple=np.tile(lam, (P, 1)).astype(f32),
        robustness=p.astype(f32),
        prior=q.astype(f32),
        valid=np.ones((T, P, K), bool),
        pose_valid=np.ones(P, bool),
        **_no_geometry((T, P, K)),
        meta={
            "source": "family",
            "prior": "family",
            "geometry": False,
            "seed": int(seed),
            "family": dict(
                shape=shape,
                excellent=float(excellent),
                auc=float(auc),
                calibration=calibration,
                num_poses=int(P),
                effective_poses=float(effective_poses),
            ),
        },
    ).validate()


def _levels(x: np.ndarray, n: int) -> np.ndarray:
    """x in [0, 1] rounded to the levels k / n (float64)."""
    return np.rint(np.clip(x, 0.0, 1.0) * n) / n


# ====================================================================== features
def concordance(
    p: np.ndarray, q: np.ndarray, rng: np.random.Generator | None = None, m: int = 400
) -> float:
    """C-index of q for p: over pairs of grasps with different p, the probability
    that q ranks the better one higher (a tie in q counts one half); the ROC AUC of
    q when the label is "the better of the pair". At most ``m`` grasps (a random
    subset when ``rng`` is given, else the first) enter; NaN with fewer than two
    distinct p."""
    p = np.asarray(p, np.float64).ravel()
    q = np.asarray(q, np.float64).ravel()
    if p.size > m:
        idx = rng.choice(p.size, m, replace=False) if rng is not None else slice(m)
        p, q = p[idx], q[idx]
    dp = np.sign(p[:, None] - p[None, :])
    dq = np.sign(q[:, None] - q[None, :])
    pairs = dp > 0
    n = int(pairs.sum())
    if n == 0:
        return float("nan")
    agree = dq[pairs]
    return float(((agree > 0).sum() + 0.5 * (agree == 0).sum()) / n)


def features(
    problem: Problem,
    *,
    horizon: int = 3000,
    k: int = 100,
    max_trials: int | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """What the regimes map is drawn over, measured on one problem.

    Per (trial, pose) over its valid grasps, then averaged over trials and over
    poses weighted by λ (poses without valid grasps left out):

    - ``mean_over_best``: mean p / p* (the typical grasp relative to the best);
    - ``share_near``, ``count_near``: share and number of grasps with p ≥ p* − 0.05
      (``count_near`` is the λ-weighted median over poses of the trials' mean);
    - ``p_star``: the best p;
    - ``auc``: the prior's C-index (:func:`concordance`, 400 random grasps a pool);
    - ``calibration``: mean q − mean p (> 0: optimistic);

    and over the object: ``effective_poses`` = 1/Σλ², and
    ``attempts_per_active`` = Σ_s λ_s · λ_s H / min(k, valid grasps of s), the
    λ-weighted mean of the attempts a pose's active grasp gets in H steps.
    """
    rng = np.random.default_rng(seed)
    T = (
        problem.num_trials
        if max_trials is None
        else min(max_trials, problem.num_trials)
    )
    lam = np.asarray(problem.landing, np.float64)
    P = problem.num_poses
    stats = {n: np.full((T, P), np.nan) for n in ("ratio", "share", "count", "pstar")}
    stats["auc"] = np.full((T, P), np.nan)
    stats["calib"] = np.full((T, P), np.nan)
    n_valid = np.zeros(P)
    for t in range(T):
        for s in range(P):
            v = problem.valid[t, s]
            if not problem.pose_valid[s] or not v.any():
                continue
            p = problem.robustness[t, s][v].astype(np.float64)
            q = problem.prior[t, s][v].astype(np.float64)
            ps = p.max()
            n_valid[s] = max(n_valid[s], v.sum())
            near = p >= ps - NEAR
            stats["ratio"][t, s] = p.mean() / ps if ps > 0 else np.nan
            stats["share"][t, s] = near.mean()
            stats["count"][t, s] = near.sum()
            stats["pstar"][t, s] = ps
            stats["auc"][t, s] = concordance(p, q, rng)
            stats["calib"][t, s] = q.mean() - p.mean()

    per_pose = {n: np.nanmean(a, axis=0) for n, a in stats.items()}
    ok = {n: np.isfinite(a) & (lam > 0) for n, a in per_pose.items()}

    def wmean(n: str) -> float:
        w = lam[ok[n]]
        return float(np.sum(w * per_pose[n][ok[n]]) / w.sum()) if w.sum() else np.nan

    def wmedian(n: str) -> float:
        x, w = per_pose[n][ok[n]], lam[ok[n]]
        if not w.sum():
            return float("nan")
        order = np.argsort(x)
        cw = np.cumsum(w[order]) / w.sum()
        return float(x[order][np.searchsorted(cw, 0.5)])

    active = np.minimum(k, np.maximum(n_valid, 1))
    return {
        "mean_over_best": wmean("ratio"),
        "share_near": wmean("share"),
        "count_near": wmedian("count"),
        "p_star": wmean("pstar"),
        "auc": wmean("auc"),
        "calibration": wmean("calib"),
        "effective_poses": float(1.0 / np.sum(lam**2)),
        "attempts_per_active": float(np.sum(lam * lam * horizon / active)),
    }


def describe(family: Mapping[str, Any]) -> str:
    """A short label of a family's arguments (figures, tables)."""
    return ", ".join(f"{k}={v}" for k, v in family.items())
