"""Verified stopping: before it stops, the robot tests its frozen recommendations.

A lower bound checked every 100 steps is read many times, and a run stops at the
first check where it reaches ρ_min. Even a bound valid at 95 % of the checks then
stops too many runs whose true performance sits just below ρ_min: each check is
another chance for the bound's noise to cross the threshold. Verification turns
the stop into a test that holds for every run, whatever the bound, the prior or
the object:

- **Trigger**: when our bound reaches ρ_min at a check, the robot freezes its
  recommendations (the grasp it would use in each pose) and starts a *phase*.
- **Attempts**: in a phase the object is dropped as usual and the robot uses the
  frozen recommendation of the pose it lands in. Under the model (poses land
  i.i.d. from λ, outcomes Bernoulli given the grasp) every attempt succeeds with
  probability τ = Σ_s λ_s p[s, rec(s)], the true performance of the frozen
  recommendations, independently of the others. The attempts are steps.
- **Test**: with k successes in n attempts, the mixture likelihood ratio

      M_n = ∫_ρ^1 p^k (1 − p)^(n − k) dp / ((1 − ρ) ρ^k (1 − ρ)^(n − k))

  (the uniform mixture over alternatives p ≥ ρ, against p = ρ) is a nonnegative
  supermartingale whenever τ ≤ ρ: one attempt multiplies it by
  (p/ρ)^x ((1 − p)/(1 − ρ))^(1 − x), whose mean τ p / ρ + (1 − τ)(1 − p)/(1 − ρ)
  is 1 at τ = ρ and grows with τ (p ≥ ρ), so it is at most 1 for τ ≤ ρ. By
  Ville's inequality P(M_n ≥ 1/δ_j for some n) ≤ δ_j: the phase *certifies*
  ρ_min (and the run stops) when M_n reaches 1/δ_j, checked after every attempt.
- **Giving up**: the mirrored ratio (the uniform mixture over p ≤ ρ) reaching
  1/δ_j says τ < ρ just as firmly; the phase ends and exploration resumes. Leaving
  a phase can never stop a run, so it costs no validity.
- **Spending**: phase j uses δ_j = δ / (j (j + 1)), which sums to δ over all
  phases, so P(a run stops with τ < ρ_min) ≤ δ for every run.

Nothing here is tuned: the mixtures are uniform, the spending is the standard
one, and the bound only decides *when* to test (a poor bound costs attempts, not
validity). Ground truth never enters the test; in simulation it is what the
attempts' outcomes are drawn from, as for every other step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import betainc, betaln

from legs_jax.core.constants import DELTA_STOP

__all__ = [
    "CERTIFIED",
    "REFUTED",
    "Verification",
    "log_evidence",
    "simulate_stops",
    "spend",
]

CERTIFIED = "certified"
REFUTED = "refuted"


def spend(phase, delta: float):
    """δ_j = δ / (j (j + 1)) of phase j = 1, 2, ... (the phases' sum is δ)."""
    j = np.asarray(phase, np.float64)
    return delta / (j * (j + 1.0))


def log_evidence(k, n, rho: float, above: bool = True):
    """log M_n: the uniform mixture over p ≥ ρ (``above``) or p ≤ ρ, against
    p = ρ, of k successes in n attempts (arrays broadcast; -inf where the
    mixture's mass underflows)."""
    k = np.asarray(k, np.float64)
    n = np.asarray(n, np.float64)
    if not 0.0 < rho < 1.0:
        raise ValueError(f"rho must be in (0, 1), got {rho!r}")
    a, b = k + 1.0, n - k + 1.0
    # mass of Beta(a, b) above (or below) rho
    mass = betainc(b, a, 1.0 - rho) if above else betainc(a, b, rho)
    width = (1.0 - rho) if above else rho
    with np.errstate(divide="ignore"):
        return (
            betaln(a, b)
            + np.log(mass)
            - math.log(width)
            - k * math.log(rho)
            - (n - k) * math.log1p(-rho)
        )


@dataclass
class Verification:
    """One run's verification at threshold ``rho``: phases, and the attempts of
    the current one. ``start()`` opens a phase (at a trigger); ``record(x)`` adds
    an attempt's outcome and returns :data:`CERTIFIED` (stop), :data:`REFUTED`
    (the phase ends, exploration resumes) or None (attempt again)."""

    rho: float
    delta: float = DELTA_STOP
    phase: int = 0
    successes: int = 0
    attempts: int = 0
    active: bool = False

    def start(self) -> None:
        self.phase += 1
        self.successes = self.attempts = 0
        self.active = True

    @property
    def level(self) -> float:
        return float(spend(max(self.phase, 1), self.delta))

    def record(self, success: bool) -> str | None:
        if not self.active:
            raise RuntimeError("no verification phase is open (call start() first)")
        self.attempts += 1
        self.successes += int(bool(success))
        cert, gone = _decide(
            self.successes, self.attempts, self.rho, -math.log(self.level)
        )
        if cert or gone:
            self.active = False
            return CERTIFIED if cert else REFUTED
        return None


def _decide(k, n, rho: float, need):
    """(certified, refuted) after k successes in n attempts: each mixture ratio
    against p = rho reaching ``need`` = log(1/δ_j) (arrays broadcast)."""
    return (
        log_evidence(k, n, rho) >= need,
        log_evidence(k, n, rho, above=False) >= need,
    )


def _first(hit: np.ndarray) -> np.ndarray:
    """Index of the first True per row, the row's length where none."""
    return np.where(hit.any(axis=1), hit.argmax(axis=1), hit.shape[1])


def simulate_stops(
    trigger: np.ndarray,
    truth: np.ndarray,
    steps: np.ndarray,
    rho: float,
    horizon: int,
    rng: np.random.Generator,
    delta: float = DELTA_STOP,
    after: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Verified stopping replayed on recorded runs.

    Args:
      trigger: [R, C] the bound at each run's checks (NaN: no check); a phase
        starts at a check where it is ≥ ``rho``.
      truth: [R, C] the true performance of the recommendations at each check:
        the success probability of one verification attempt from there.
      steps: [C] the exploration step of each check.
      rho, horizon, delta: the threshold, the step budget H, δ_stop.
      rng: draws the attempts' outcomes (Bernoulli(truth)).
      after: [R, C] mean attempts after a failed attempt at a landing until the
        next success, the recommendations frozen at that check (the engine's
        ``check_after_failure``); NaN or None where not recorded, where each
        failure is followed by a geometric number at rate ``truth`` instead, an
        approximation that undercounts when the toppled poses are harder.
    Returns:
      ``stopped`` [R] bool, ``stop_step`` [R] (the step of the last certifying
      attempt, exploration and every attempt counted; ``horizon`` where the run
      never stops), ``truth`` [R] (of the certified recommendations; NaN where
      not stopped), ``attempts`` [R] (verification attempts spent in all).

    A phase started at check c (exploration step steps[c], after ``spent``
    earlier attempts) may use the attempts left in the budget, H − steps[c] −
    spent; a phase that neither certifies nor gives up within them ends the run
    unstopped. Exploration is replayed as recorded: the outcomes of a phase that
    gives up do not feed the method (a real robot would learn from them too).
    """
    trig = np.nan_to_num(np.asarray(trigger, np.float64), nan=-np.inf)
    tru = np.asarray(truth, np.float64)
    steps = np.asarray(steps, np.int64)
    R, C = trig.shape
    stopped = np.zeros(R, bool)
    stop_step = np.full(R, float(horizon))
    at_stop = np.full(R, np.nan)
    spent = np.zeros(R, np.float64)
    phase = np.zeros(R, np.int64)
    over = np.zeros(R, bool)  # the budget ran out
    known_after = (
        np.full(trig.shape, np.nan) if after is None else np.asarray(after, np.float64)
    )
    for c in range(C):
        rows = np.flatnonzero(~stopped & ~over & (trig[:, c] >= rho))
        if rows.size == 0:
            continue
        left = np.floor(horizon - steps[c] - spent[rows]).astype(np.int64)
        ok = left > 0
        over[rows[~ok]] = True
        rows, left = rows[ok], left[ok]
        if rows.size == 0:
            continue
        phase[rows] += 1
        tau = tru[rows, c]
        first, how, wins = _phase(tau, left, spend(phase[rows], delta), rho, rng)
        # After a failed attempt the object lies where it toppled, and the robot
        # tries again until a success drops it: those attempts are steps, not
        # samples of the test. Their mean where the run recorded it, else a
        # geometric number at the success rate tau (an approximation).
        fails = first - wins
        guess = fails + rng.negative_binomial(
            np.maximum(fails, 1), np.clip(tau, 1e-6, 1.0)
        ) * (fails > 0)
        known = known_after[rows, c]
        with np.errstate(invalid="ignore"):
            exact = np.where(fails > 0, fails * known, 0.0)
        used = first + np.where(np.isnan(known), guess, exact)
        win = (how == 1) & (used <= left)
        stopped[rows[win]] = True
        stop_step[rows[win]] = steps[c] + spent[rows[win]] + used[win]
        at_stop[rows[win]] = tau[win]
        spent[rows] += np.minimum(used, left)
        over[rows[~win & ((how == 0) | (used >= left))]] = True
    return dict(stopped=stopped, stop_step=stop_step, truth=at_stop, attempts=spent)


# Attempts of the phases drawn and tested this many at a time.
_BLOCK = 128


def _phase(tau, left, level, rho, rng):
    """Phases run side by side: attempts succeed with probability ``tau``, at most
    ``left`` of them, at level ``level``. Returns (attempts used, outcome: 1
    certified, 2 gave up, 0 out of budget, successes among the attempts used),
    each [rows]."""
    rows = tau.shape[0]
    need = -np.log(level)
    k = np.zeros(rows, np.int64)
    used = np.zeros(rows, np.int64)
    how = np.zeros(rows, np.int64)
    todo = np.arange(rows)
    n0 = 0
    while todo.size:
        x = rng.random((todo.size, _BLOCK)) < tau[todo, None]
        kk = k[todo, None] + np.cumsum(x, axis=1)
        n = n0 + np.arange(1, _BLOCK + 1)[None, :]
        within = n <= left[todo, None]
        cert, gone = _decide(kk, n, rho, need[todo, None])
        cert, gone = cert & within, gone & within
        fc, fg = _first(cert), _first(gone)
        end_c = fc < np.minimum(fg, _BLOCK)
        end_g = ~end_c & (fg < _BLOCK)
        out = ~end_c & ~end_g & (n[0, -1] >= left[todo])  # budget spent in block
        used[todo[end_c]] = n0 + fc[end_c] + 1
        used[todo[end_g]] = n0 + fg[end_g] + 1
        used[todo[out]] = left[todo[out]]
        end = np.where(end_c, fc, np.where(end_g, fg, _BLOCK - 1))
        end = np.minimum(end, np.maximum(left[todo] - n0 - 1, 0))
        k[todo] = np.take_along_axis(kk, end[:, None], axis=1)[:, 0]
        how[todo[end_c]] = 1
        how[todo[end_g]] = 2
        todo = todo[~(end_c | end_g | out)]
        n0 += _BLOCK
    return used, how, k
