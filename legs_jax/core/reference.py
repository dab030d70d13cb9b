"""Plain NumPy reference implementation of every method and metric.

One rollout at a time, one step at a time, the way the original research code
works. It is the oracle the JAX engine is tested against and the baseline of the
speed benchmark: readable first, but not artificially slow (within a step the K
arms are handled as NumPy vectors; steps and rollouts are Python loops).

Dimension letters: T trials, R rollouts, P poses, K grasps per pose, k active-set
size, H horizon, C1 recorded gap steps, C2 Dirichlet checks.

Rules this module fixes (the JAX engine follows the same ones)
------------------------------------------------------------------

Random streams.
  Rollout ``r`` of trial ``t`` draws everything from one ``np.random.Generator``
  seeded with ``SeedSequence([seed, t, r])`` (so a rollout's result does not depend
  on which other trials or rollouts run beside it). It is split by ``spawn(3)``
  into an environment stream, a method stream and a stopping-check stream, so that
  methods see common random numbers and the checks never change a trajectory. The
  environment pre-draws ``u0`` (first drop), ``u_reward[H]`` and ``u_move[H]``;
  the reward of step t is ``u_reward[t-1] < p[s, a]`` and the next pose is the
  inverse CDF of the landing row (after a success) or of the topple row of s
  (after a failure) at ``u_move[t-1]``.

Order of one step t = 1..H.
  select a grasp of the current pose s -> reward -> posterior / Q update ->
  LEGS(-AS) pruning of pose s if ``t % n == 0`` -> transition to s' (a drop after
  a success, counted in c_{s'}; a topple after a failure) -> gap recorded if
  ``t % record_every == 0`` or ``t == H`` -> Dirichlet check if
  ``t % check_every == 0``. The gap at step 0 is recorded after the first drop,
  before any grasp.

A pose with no valid grasp.
  The environment still lands in it. The method cannot grasp there: the step counts
  as a failed grasp attempt (r = 0) that touches no grasp, so nothing is learned,
  no counter changes and no pruning happens; the object then moves by the topple
  row of that pose, like any failure. Its recommendation is "none" (-1): it adds 0
  to the gap (p*_s = 0) and 0 to the performance; in the Dirichlet check its
  estimate p̂*_s is 0.

Prior, posterior and rankings.
  q is clipped to [0.01, 0.99] only inside the Beta parameters:
  α = prior_offset + s·q_c + S, β = prior_offset + s·(1 − q_c) + F. Every ranking
  "by q" (Dex-Net's choice, the top-100 and top-k sets, LEGS's refill order, the
  recommendation of an unvisited pose) and TQL's Q₀ use the raw q. Rankings are
  stable: equal q keep the lower grasp index first.

Recommendation π_t(s).
  Dex-Net: argmax q over all valid grasps. K100 upper bound: argmax p over the
  top-100 by q. TQL: argmax Q over the valid grasps (Q₀ = q, so a pose never
  grasped gets argmax q). Beta methods: argmax posterior mean over the method's
  current candidates of s once s is *visited*, else argmax q over them. Visited
  is Algorithm 1's set Ŝ: the poses in which at least one grasp was attempted
  (a pose just landed in is not visited until the next step grasps in it). All
  ties, here and in Thompson draws, go to the lowest grasp index.

LEGS.
  The active set of a pose is its top-k valid grasps by q (fewer slots filled if
  the pose has fewer valid grasps); the rest, in descending q, is its refill queue.
  Algorithm 1 builds it at the first visit; since it depends on nothing learned,
  building every pose's set at step 0 is the same thing and is what this module
  does (an unvisited pose's candidates are this initial set). Pruning uses
  :func:`legs_prune`; removed slots, in slot order, take the next grasps of the
  queue; when it runs out the slot stays empty (-1). LEGS(-AS) applies the same
  rule to all valid grasps of the pose, without refill. ``replacements`` counts
  removed grasps.

Constant rows.
  Dex-Net and the K100 upper bound run in the environment with their fixed grasp
  (so successes and counters are real); their gap is constant. They keep a Beta
  posterior of their candidates that never drives a choice and serves only the
  Dirichlet check.

Dirichlet stopping check.
  c_s counts drops (the first one and every one after a success); observed poses
  are those landed in or toppled into so far. p̂*_s = max posterior mean (TQL: max
  Q) over the candidates of s; the *attempted* variant takes the max over the
  candidates attempted at least once (0 if none). The quantile is δ_stop = 0.05
  (fixed, independent of the pruning δ) of M = 3000 samples, linear
  interpolation (``np.quantile``); both variants use the same samples.

Methods.
  Each method (:mod:`legs_jax.core.methods`) names its NumPy twin in its declaration
  (``Method.card.reference``, one of the classes below or the user's own); this
  module's loop, environment and checks are shared by all of them.

Validation.
  :func:`check_hparams` applies the method's own declaration, as the engine does
  (:func:`legs_jax.core.methods.parse_grid`): an unknown method or hyperparameter, a
  value outside its declared range, s = prior_offset = 0, and k > K for LEGS raise
  :class:`legs_jax.errors.ConfigError`. BORGES (K=100) and the K100 upper bound
  always use the top 100 (or every valid grasp when a pose has fewer).

Why one file: this is the plain NumPy reference that the engine and every method are
checked against (``tests/test_parity.py``), meant to be read beside Algorithm 1. Its
validation, metrics, environment, method protocol and rollout loop are each short
and call one another; spread over modules they would no longer be the one place
where a reader checks the engine.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from legs_jax.core import methods
from legs_jax.core.constants import DELTA_STOP, NUM_DIRICHLET_SAMPLES
from legs_jax.core.methods.base import Config
from legs_jax.core.problem import Problem
from legs_jax.errors import ConfigError

__all__ = [
    "DELTA_STOP",
    "NUM_DIRICHLET_SAMPLES",
    "ReferenceMethod",
    "RunResult",
    "check_hparams",
    "constant_gap",
    "constant_policy",
    "dirichlet_lower_bound",
    "gap",
    "legs_prune",
    "performance",
    "prior_choice",
    "rank_by_prior",
    "masked_argmax",
    "rollout_rng",
    "run",
    "run_rollout",
    "top_mask",
    "top_truth_choice",
]


class RunResult(NamedTuple):
    """Results of :func:`run`; leading axes [G=1, O=1, T, R] like the engine's."""

    final_gap: np.ndarray  # [1, 1, T, R] gap Δ_H
    final_performance: np.ndarray  # [1, 1, T, R] Σ_s λ_s p[s, π_H(s)]
    successes: np.ndarray  # [1, 1, T, R] number of successful grasps
    distinct_grasps: np.ndarray  # [1, 1, T, R] distinct (pose, grasp) attempted
    replacements: np.ndarray  # [1, 1, T, R] grasps removed by LEGS(-AS) pruning
    curve_steps: np.ndarray  # [C1] 0, record_every, ..., H
    gap_curve: np.ndarray  # [1, 1, T, R, C1]
    check_steps: np.ndarray  # [C2] check_every, 2·check_every, ... <= H
    check_p_lower: np.ndarray  # [1, 1, T, R, C2] p̂_ℓ, p̂* over all candidates
    check_p_lower_attempted: np.ndarray  # [1, 1, T, R, C2] p̂* over attempted ones
    check_true_performance: np.ndarray  # [1, 1, T, R, C2]
    active_set: np.ndarray | None  # [1, 1, T, R, C2, P, k] grasp ids, -1 empty


# ---------------------------------------------------------------- validation


def check_hparams(
    problem: Problem, method: Any, hparams: Mapping[str, Any] | None = None
) -> dict[str, float | int]:
    """Complete ``hparams`` with the method's defaults and validate them (the
    engine's rules, :func:`legs_jax.core.methods.parse_grid`), one value each.

    Raises :class:`ConfigError` with a one-line message (see the module docstring).
    """
    m = methods.resolve(method)
    for name, value in (hparams or {}).items():
        if isinstance(value, (str, bytes)) or np.ndim(value) != 0:
            raise ConfigError(
                f"hyperparameter '{name}' must be one number here, got {value!r} "
                "(the reference runs one configuration at a time)"
            )
    _, grid = methods.parse_grid(m, hparams, problem.num_grasps)
    return {name: v[0].item() for name, v in grid.items()}


def _check_run_args(
    problem: Problem, horizon: int, record_every: int, check_every: int
) -> None:
    if not isinstance(problem, Problem):
        raise ConfigError(
            f"expected a legs_jax.core.problem.Problem, got {type(problem)}"
        )
    for name, value in (
        ("horizon", horizon),
        ("record_every", record_every),
        ("check_every", check_every),
    ):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
        if value < 1:
            raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")


# ---------------------------------------------------------------- metrics


def _trial_arrays(problem: Problem, trial: int):
    """(λ [P], p [P, K], q [P, K], valid [P, K]) of one trial, in float64."""
    lam = problem.landing.astype(np.float64)
    p = problem.robustness[trial].astype(np.float64)
    q = problem.prior[trial].astype(np.float64)
    valid = problem.valid[trial] & problem.pose_valid[:, None]
    return lam, p, q, valid


def performance(problem: Problem, trial: int, policy: np.ndarray) -> float:
    """Σ_s λ_s p[s, π(s)]; a pose with π(s) = -1 (no valid grasp) adds 0."""
    lam, p, _, valid = _trial_arrays(problem, trial)
    policy = np.asarray(policy)
    has = policy >= 0
    idx = np.where(has, policy, 0)
    if np.any(has & ~valid[np.arange(len(policy)), idx]):
        raise ValueError("policy selects an invalid grasp")
    chosen = np.where(has, p[np.arange(len(policy)), idx], 0.0)
    return float(np.sum(lam * chosen))


def gap(problem: Problem, trial: int, policy: np.ndarray) -> float:
    """Optimality gap, eq. 3.1: Σ_s λ_s (p*_s − p[s, π(s)]).

    Args:
      policy: [P] grasp index per pose (-1 only for a pose with no valid grasp).
    """
    lam, p, _, valid = _trial_arrays(problem, trial)
    p_star = np.where(valid, p, 0.0).max(axis=1)  # [P]
    return float(np.sum(lam * p_star)) - performance(problem, trial, policy)


def rank_by_prior(q_row: np.ndarray, valid_row: np.ndarray) -> np.ndarray:
    """Valid grasp indices of one pose in descending q (ties: lower index first)."""
    idx = np.flatnonzero(valid_row)
    return idx[np.argsort(-q_row[idx], kind="stable")]


def top_mask(q: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """[P, K] bool: the top-``size`` valid grasps of each pose by q."""
    mask = np.zeros_like(valid)
    for s in range(q.shape[0]):
        mask[s, rank_by_prior(q[s], valid[s])[:size]] = True
    return mask


def masked_argmax(score: np.ndarray, mask: np.ndarray) -> int:
    """Lowest index of the max of ``score`` over ``mask`` (-1 if mask is empty)."""
    idx = np.flatnonzero(mask)  # ascending, so argmax's first max is the lowest
    return int(idx[np.argmax(score[idx])]) if idx.size else -1


def prior_choice(problem: Problem, trial: int) -> np.ndarray:
    """[P] the grasp of highest q of each pose (Dex-Net's), -1 with none."""
    _, _, q, valid = _trial_arrays(problem, trial)
    return np.array([masked_argmax(q[s], valid[s]) for s in range(len(q))])


def top_truth_choice(problem: Problem, trial: int, size: int) -> np.ndarray:
    """[P] the grasp of highest p among the top ``size`` by q (the K100 upper
    bound's), -1 with none."""
    _, p, q, valid = _trial_arrays(problem, trial)
    cand = top_mask(q, valid, size)
    return np.array([masked_argmax(p[s], cand[s]) for s in range(len(p))])


def constant_policy(problem: Problem, method: Any, trial: int) -> np.ndarray:
    """[P] fixed grasp per pose of a constant row (a method that does not learn)."""
    m = methods.resolve(method)
    twin = m.card.reference(problem, trial, m.defaults()) if m.card.reference else None
    if m.learns or getattr(twin, "choice", None) is None:
        raise ConfigError(f"{m.name} is not a constant row")
    return twin.choice.copy()


def constant_gap(problem: Problem, method: Any, trial: int) -> float:
    """The constant gap of a constant row (Dex-Net, K100 upper bound)."""
    return gap(problem, trial, constant_policy(problem, method, trial))


def legs_prune(
    alpha: np.ndarray,
    beta: np.ndarray,
    attempted: np.ndarray,
    active: np.ndarray,
    delta: float,
    gamma: float,
) -> np.ndarray:
    """The LEGS removal set B of one pose, as a bool mask over arms.

    B = { i active : i attempted, i ≠ i*, X_{i,u} < X*_ℓ or X_{i,u} < γ }, with
    X_{i,ℓ} = PPF(Beta(α_i, β_i), δ), X_{i,u} = PPF(Beta(α_i, β_i), 1 − δ),
    X*_ℓ = max over the active arms of X_{i,ℓ} and i* = argmax posterior mean
    α/(α+β) over the active arms (ties: lowest index).

    Args:
      alpha, beta: [N] Beta parameters of the arms (prior offset included).
      attempted: [N] bool, arm tried at least once.
      active: [N] bool, arm in the active (candidate) set.
    Returns:
      [N] bool, True for the arms to remove (always a subset of ``active``).
    """
    alpha = np.asarray(alpha, np.float64)
    beta = np.asarray(beta, np.float64)
    removed = np.zeros(alpha.shape, bool)
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return removed
    a, b = alpha[idx], beta[idx]
    from scipy.special import betaincinv  # imported here: 0.1 s at start-up

    lower = betaincinv(a, b, delta)  # X_{i,ℓ}
    upper = betaincinv(a, b, 1.0 - delta)  # X_{i,u}
    x_star_lower = lower.max()  # X*_ℓ
    i_star = idx[np.argmax(a / (a + b))]  # idx is ascending: ties -> lowest index
    removable = np.asarray(attempted)[idx] & (idx != i_star)
    removed[idx] = removable & ((upper < x_star_lower) | (upper < gamma))
    return removed


def dirichlet_lower_bound(
    counts: np.ndarray,
    observed: np.ndarray,
    values: np.ndarray,
    delta: float,
    num_samples: int,
    rng: np.random.Generator,
) -> float | np.ndarray:
    """The δ-quantile of p' = Σ_{observed s} v_s λ'_s (Section 4.4).

    λ' ~ Dir(c_s + 1 for each observed pose, 1 for one "unseen" bin whose value is
    0); unobserved poses get no bin. The quantile of the ``num_samples`` values of
    p' uses linear interpolation (``np.quantile``).

    Args:
      counts: [P] drop counts c_s.
      observed: [P] bool, pose observed so far.
      values: [P] p̂*_s, or [V, P] for V value vectors scored on the same samples.
      delta: the quantile δ_stop.
      num_samples: M.
      rng: consumed.
    Returns:
      p̂_ℓ, a float (or [V] for [V, P] values).
    """
    observed = np.asarray(observed, bool)
    values = np.asarray(values, np.float64)
    if not observed.any():
        return 0.0 if values.ndim == 1 else np.zeros(values.shape[0])
    alpha = np.append(np.asarray(counts, np.float64)[observed] + 1.0, 1.0)
    lam = rng.dirichlet(alpha, size=num_samples)  # [M, N_obs + 1]
    p = lam[:, :-1] @ values[..., observed].T  # [M] or [M, V]
    bound = np.quantile(p, delta, axis=0)
    return float(bound) if values.ndim == 1 else bound


# ---------------------------------------------------------------- environment


class _Environment:
    """Drops and topples of one object, by inverse CDF of a uniform."""

    def __init__(self, problem: Problem):
        landing = np.where(problem.pose_valid, problem.landing, 0.0)
        topple = np.where(problem.pose_valid[None, :], problem.topple, 0.0)
        self.landing_cdf = self._cdf(landing)
        self.topple_cdf = [self._cdf(row) for row in topple]

    @staticmethod
    def _cdf(probs: np.ndarray) -> tuple[list[float], int]:
        """Cumulative sums (float64, as a list) and the last pose of positive
        probability."""
        probs = probs.astype(np.float64)
        positive = np.flatnonzero(probs > 0)  # empty only for a padded pose's row
        return np.cumsum(probs).tolist(), int(positive[-1]) if positive.size else -1

    @staticmethod
    def _draw(cdf: tuple[list[float], int], u: float) -> int:
        # bisect_right: the first pose whose cdf exceeds u·total; it always has
        # positive probability, so padded and impossible poses are never drawn
        # (the min guards against rounding at the very top).
        sums, last = cdf
        return min(bisect.bisect_right(sums, u * sums[-1]), last)

    def drop(self, u: float) -> int:
        return self._draw(self.landing_cdf, u)

    def topple(self, s: int, u: float) -> int:
        return self._draw(self.topple_cdf[s], u)


# ---------------------------------------------------------------- methods


class ReferenceMethod:
    """Per-rollout state of one method on one trial's reservoir.

    ``cand`` [P, K] is the method's current candidate set of each pose;
    :func:`run_rollout` calls ``select``, ``update``, ``after_step``,
    ``recommend`` and ``estimates``.
    """

    def __init__(self, problem: Problem, trial: int, hp: Mapping[str, Any]):
        _, self.p, self.q, self.valid = _trial_arrays(problem, trial)
        self.hp = hp
        P, K = self.q.shape
        self.cand = self.valid.copy()  # [P, K] candidate set
        self.attempted = np.zeros((P, K), bool)  # [P, K] tried at least once
        self.visited = np.zeros(P, bool)  # [P] Algorithm 1's Ŝ
        self.replacements = 0
        self.removal_log: list[tuple[int, int, int]] = []  # (step, pose, grasp)
        # [P] the fixed grasp of each pose of a constant row (None: it learns)
        self.choice: np.ndarray | None = None
        self._policy = np.full(P, -1)  # cached recommendation
        self._dirty = np.ones(P, bool)  # poses whose recommendation may change

    def select(self, s: int, rng: np.random.Generator) -> int:
        raise NotImplementedError

    def update(self, s: int, a: int, r: bool) -> None:
        self.attempted[s, a] = True
        self.visited[s] = True
        self._dirty[s] = True

    def after_step(self, t: int, s: int) -> None:
        """Hook after the update of global step t on pose s (LEGS pruning)."""

    def _recommend_pose(self, s: int) -> int:
        raise NotImplementedError

    def recommend(self) -> np.ndarray:
        """[P] π_t(s), -1 for a pose without candidates."""
        for s in np.flatnonzero(self._dirty):
            self._policy[s] = self._recommend_pose(s)
        self._dirty[:] = False
        return self._policy.copy()

    def _score(self) -> np.ndarray:
        """[P, K] the value estimate behind p̂* (posterior mean or Q)."""
        raise NotImplementedError

    def estimates(self) -> np.ndarray:
        """[2, P]: p̂*_s over all candidates, and over attempted candidates only."""
        score = self._score()
        out = np.zeros((2, score.shape[0]))
        for row, mask in enumerate((self.cand, self.cand & self.attempted)):
            best = np.where(mask, score, -np.inf).max(axis=1)
            out[row] = np.where(mask.any(axis=1), best, 0.0)
        return out

    def active_slots(self, k: int) -> np.ndarray:
        """[P, k] grasp ids of each pose's active set (-1 empty); LEGS only."""
        return np.full((self.q.shape[0], k), -1)


# ---------------------------------------------------------------- rollouts


def _curve_steps(horizon: int, record_every: int) -> np.ndarray:
    return np.unique(np.append(np.arange(0, horizon + 1, record_every), horizon))


def _check_steps(horizon: int, check_every: int) -> np.ndarray:
    return np.arange(check_every, horizon + 1, check_every)


def run_rollout(
    problem: Problem,
    trial: int,
    method: str,
    hparams: Mapping[str, Any] | None,
    rng: np.random.Generator,
    horizon: int,
    record_every: int,
    check_every: int,
    record_active_set: bool = False,
) -> dict[str, Any]:
    """One rollout of ``method`` on one trial's reservoir.

    Args:
      rng: consumed; split into environment, method and check streams.
    Returns:
      a dict with the per-rollout fields of :class:`RunResult` (``final_gap``,
      ``final_performance``, ``successes``, ``distinct_grasps``, ``replacements``,
      ``gap_curve`` [C1], ``check_p_lower`` [C2], ``check_p_lower_attempted`` [C2],
      ``check_true_performance`` [C2], ``active_set`` [C2, P, k] or None) and the
      trajectory: ``poses`` [H] (pose of each step), ``actions`` [H] (grasp, -1
      when the pose has none), ``rewards`` [H] bool, ``final_policy`` [P] and
      ``removals``, the (step, pose, grasp) of every grasp LEGS(-AS) removed, and
      the final ``drop_counts`` c [P] and ``observed`` [P] of the stopping check.
    """
    _check_run_args(problem, horizon, record_every, check_every)
    hp = check_hparams(problem, method, hparams)
    spec = _method(method)
    if not 0 <= trial < problem.num_trials:
        raise ConfigError(
            f"trial {trial} out of range: problem '{problem.name}' has "
            f"{problem.num_trials} trials"
        )
    H, P = horizon, problem.num_poses
    env_rng, method_rng, check_rng = rng.spawn(3)
    u_drop0 = env_rng.random()
    u_reward = env_rng.random(H)
    u_move = env_rng.random(H)

    env = _Environment(problem)
    m = spec.card.reference(problem, trial, hp)
    lam, p, _, valid = _trial_arrays(problem, trial)
    has_grasp = valid.any(axis=1)  # [P]
    total_star = float(np.sum(lam * np.where(valid, p, 0.0).max(axis=1)))
    rows = np.arange(P)

    def perf(policy: np.ndarray) -> float:
        chosen = np.where(policy >= 0, p[rows, np.maximum(policy, 0)], 0.0)
        return float(np.sum(lam * chosen))

    curve_steps = _curve_steps(H, record_every)
    check_steps = _check_steps(H, check_every)
    gap_curve = np.zeros(curve_steps.size)
    p_lower = np.zeros((2, check_steps.size))
    true_perf = np.zeros(check_steps.size)
    static = {n: hp[n] for n in spec.static}
    width = spec.active_width(Config(P, problem.num_grasps, **static))  # slots
    active = np.full((check_steps.size, P, width), -1) if record_active_set else None
    poses = np.zeros(H, int)
    actions = np.full(H, -1)
    rewards = np.zeros(H, bool)

    drops = np.zeros(P, int)  # c_s
    observed = np.zeros(P, bool)
    s = env.drop(u_drop0)
    drops[s] += 1
    observed[s] = True
    gap_curve[0] = total_star - perf(m.recommend())
    i_curve, i_check = 1, 0
    successes = 0

    for t in range(1, H + 1):
        if has_grasp[s]:
            a = m.select(s, method_rng)
            r = bool(u_reward[t - 1] < p[s, a])
            m.update(s, a, r)
            m.after_step(t, s)  # the twin's own pruning (LEGS(-AS): t % n == 0)
        else:  # no valid grasp: a failed attempt that touches no grasp
            a, r = -1, False
        poses[t - 1], actions[t - 1], rewards[t - 1] = s, a, r
        successes += r
        if r:
            s = env.drop(u_move[t - 1])
            drops[s] += 1
        else:
            s = env.topple(s, u_move[t - 1])
        observed[s] = True

        if i_curve < curve_steps.size and t == curve_steps[i_curve]:
            gap_curve[i_curve] = total_star - perf(m.recommend())
            i_curve += 1
        if i_check < check_steps.size and t == check_steps[i_check]:
            p_lower[:, i_check] = dirichlet_lower_bound(
                drops,
                observed,
                m.estimates(),  # [2, P]: both variants on the same samples
                DELTA_STOP,
                NUM_DIRICHLET_SAMPLES,
                check_rng,
            )
            true_perf[i_check] = perf(m.recommend())
            if active is not None:
                active[i_check] = m.active_slots(width)
            i_check += 1

    final_policy = m.recommend()
    return dict(
        final_gap=float(gap_curve[-1]),
        final_performance=perf(final_policy),
        successes=int(successes),
        distinct_grasps=int(m.attempted.sum()),
        replacements=int(m.replacements),
        gap_curve=gap_curve,
        check_p_lower=p_lower[0],
        check_p_lower_attempted=p_lower[1],
        check_true_performance=true_perf,
        active_set=active,
        poses=poses,
        actions=actions,
        rewards=rewards,
        final_policy=final_policy,
        removals=list(m.removal_log),
        drop_counts=drops,
        observed=observed,
    )


def _method(method: Any):
    """The registered method (a name, ``module:ATTRIBUTE`` or a Method) that has
    a NumPy twin."""
    m = methods.resolve(method)
    if m.card.reference is None:
        raise ConfigError(f"method {m.name} has no NumPy reference")
    return m


def rollout_rng(seed: int, trial: int, rollout: int) -> np.random.Generator:
    """The generator of rollout ``rollout`` of trial ``trial`` (module docstring)."""
    return np.random.default_rng(np.random.SeedSequence([seed, trial, rollout]))


def run(
    problem: Problem,
    method: str,
    *,
    trials: Sequence[int] | None = None,
    num_rollouts: int = 10,
    horizon: int = 3000,
    hparams: Mapping[str, Any] | None = None,
    seed: int = 0,
    record_every: int = 10,
    check_every: int = 100,
    record_active_set: bool = False,
    progress: bool = False,
) -> RunResult:
    """Run ``num_rollouts`` rollouts of ``method`` on each trial of ``problem``.

    Args:
      trials: trial indices (default: all T).
      hparams: overrides of the method's defaults (one value each).
      seed: non-negative integer; rollout r of trial t uses ``rollout_rng(seed,
        t, r)``.
      progress: show a progress bar over the rollouts.
    Returns:
      a :class:`RunResult` with leading axes [1, 1, T, R].
    Raises:
      ConfigError: invalid method, hyperparameters or arguments.
    """
    _check_run_args(problem, horizon, record_every, check_every)
    hp = check_hparams(problem, method, hparams)
    method = _method(method).name
    trials = list(range(problem.num_trials)) if trials is None else list(trials)
    if not trials:
        raise ConfigError("trials is empty")
    for tr in trials:
        if not isinstance(tr, (int, np.integer)) or not 0 <= tr < problem.num_trials:
            raise ConfigError(
                f"trial {tr!r} out of range: problem '{problem.name}' has "
                f"{problem.num_trials} trials"
            )
    if not isinstance(num_rollouts, (int, np.integer)) or num_rollouts < 1:
        raise ConfigError(f"num_rollouts must be an integer >= 1, got {num_rollouts!r}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")

    T, R = len(trials), int(num_rollouts)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=T * R, desc=f"reference {method}", unit="rollout")
    outs = []
    for tr in trials:
        row = []
        for r in range(R):
            rng = rollout_rng(seed, int(tr), r)
            row.append(
                run_rollout(
                    problem,
                    int(tr),
                    method,
                    hp,
                    rng,
                    horizon,
                    record_every,
                    check_every,
                    record_active_set,
                )
            )
            if bar is not None:
                bar.update(1)
        outs.append(row)
    if bar is not None:
        bar.close()

    def field(name: str, dtype=None) -> np.ndarray:
        arr = np.array([[o[name] for o in row] for row in outs], dtype=dtype)
        return arr[None, None]

    return RunResult(
        final_gap=field("final_gap", np.float64),
        final_performance=field("final_performance", np.float64),
        successes=field("successes", np.int64),
        distinct_grasps=field("distinct_grasps", np.int64),
        replacements=field("replacements", np.int64),
        curve_steps=_curve_steps(horizon, record_every),
        gap_curve=field("gap_curve", np.float64),
        check_steps=_check_steps(horizon, check_every),
        check_p_lower=field("check_p_lower", np.float64).reshape(1, 1, T, R, -1),
        check_p_lower_attempted=field("check_p_lower_attempted", np.float64).reshape(
            1, 1, T, R, -1
        ),
        check_true_performance=field("check_true_performance", np.float64).reshape(
            1, 1, T, R, -1
        ),
        active_set=field("active_set", np.int64) if record_active_set else None,
    )
