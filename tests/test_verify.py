"""Verified stopping (legs_jax.core.verify): the test's evidence, its validity at
the worst truth (the threshold itself), its power, and its replay on recorded
checks. Statistical claims use fixed seeds and binomial tolerances of 3 standard
errors."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import integrate

from legs_jax.core import verify
from legs_jax.report import analysis as an

DELTA = 0.05


def _tol(p: float, n: int) -> float:
    return 3.0 * math.sqrt(p * (1.0 - p) / n)


def _phases(tau, rho, runs, seed, budget=3000):
    """``runs`` phases side by side at level δ_1, truth ``tau``: (attempts used,
    outcome 1 certified / 2 refuted / 0 out of budget, successes)."""
    return verify._phase(
        np.full(runs, tau),
        np.full(runs, budget),
        np.full(runs, verify.spend(1, DELTA)),
        rho,
        np.random.default_rng(seed),
    )


@pytest.mark.parametrize(
    "k,n,rho", [(0, 1, 0.5), (9, 10, 0.8), (40, 50, 0.9), (3, 20, 0.3), (95, 100, 0.95)]
)
@pytest.mark.parametrize("above", [True, False])
def test_evidence_is_the_uniform_mixture_likelihood_ratio(k, n, rho, above):
    # the mixture integrated numerically, against the closed form
    lo, hi = (rho, 1.0) if above else (0.0, rho)
    num, _ = integrate.quad(
        lambda p: p**k * (1 - p) ** (n - k), lo, hi, epsabs=0, epsrel=1e-10
    )
    want = math.log(num / (hi - lo)) - k * math.log(rho) - (n - k) * math.log1p(-rho)
    assert verify.log_evidence(k, n, rho, above) == pytest.approx(want, rel=1e-7)


def test_spending_sums_to_delta():
    j = np.arange(1, 200_001)
    assert verify.spend(j, DELTA).sum() == pytest.approx(DELTA, rel=1e-4)
    assert verify.spend(1, DELTA) == DELTA / 2


def _always(rows, checks, value):
    return np.full((rows, checks), value)


@pytest.mark.parametrize(
    "rho,below",
    [
        (0.8, 0.0),
        pytest.param(0.5, 0.0, marks=pytest.mark.slow),
        pytest.param(0.9, 0.02, marks=pytest.mark.slow),
    ],
)
def test_runs_below_the_threshold_stop_at_most_delta_of_the_time(rho, below):
    # The worst case: the bound calls for a test at every check (30 of them) and
    # the truth is at (or just under) the threshold; every phase may use all the
    # attempts the budget leaves. At most δ of the runs may stop.
    runs, checks = 2000, 30
    truth = rho - below
    out = verify.simulate_stops(
        _always(runs, checks, 1.0),
        _always(runs, checks, truth),
        100 * np.arange(1, checks + 1),
        rho,
        3000,
        np.random.default_rng(1),
    )
    rate = out["stopped"].mean()
    assert rate <= DELTA + _tol(DELTA, runs), rate
    # the budget holds: nobody stops after H, and the attempts fit in it
    assert out["stop_step"].max() <= 3000
    assert (100 + out["attempts"] <= 3000).all()


def test_a_single_phase_at_the_threshold_certifies_at_most_its_level():
    # One phase at level δ_1 = δ/2 with the truth at ρ and 1500 attempts.
    rho, runs = 0.7, 3000
    used, how, _ = _phases(rho, rho, runs, 2, budget=1500)
    rate = np.mean(how == 1)
    assert rate <= DELTA / 2 + _tol(DELTA / 2, runs), rate
    # and a truth at the threshold is refuted or runs out of budget otherwise
    assert set(np.unique(how)) <= {0, 1, 2}


def test_good_recommendations_are_certified_fast():
    # τ = 0.9 against ρ = 0.8: every phase certifies, in a number of attempts of
    # the order of log(1/δ_1) / KL(τ || ρ) (a sequential probability ratio test
    # with the true alternative would need about that many).
    rho, tau, runs = 0.8, 0.9, 2000
    used, how, _ = _phases(tau, rho, runs, 3, budget=3000)
    kl = tau * math.log(tau / rho) + (1 - tau) * math.log((1 - tau) / (1 - rho))
    sprt = math.log(2 / DELTA) / kl
    assert np.mean(how == 1) >= 0.99
    assert used.mean() <= 3 * sprt, (used.mean(), sprt)


def test_poor_recommendations_are_refuted_not_tried_forever():
    rho, tau, runs = 0.8, 0.65, 2000
    used, how, _ = _phases(tau, rho, runs, 4, budget=3000)
    assert np.mean(how == 2) >= 0.99
    assert np.mean(how == 1) <= DELTA / 2 + _tol(DELTA / 2, runs)
    assert np.median(used) < 300


def test_the_session_object_agrees_with_the_batched_replay():
    # The same outcomes (the generator's first block) fed one by one.
    rho, tau = 0.75, 0.85
    used, how, wins = verify._phase(
        np.array([tau]), np.array([3000]), np.array([DELTA / 2]), rho,
        np.random.default_rng(5),
    )  # fmt: skip
    gen = np.random.default_rng(5)  # the blocks _phase draws, one row each
    draws = np.concatenate([gen.random((1, verify._BLOCK))[0] for _ in range(30)])
    draws = draws < tau
    v = verify.Verification(rho, DELTA)
    v.start()
    result = None
    for x in draws:
        result = v.record(bool(x))
        if result is not None:
            break
    assert v.attempts == used[0] and v.successes == wins[0]
    assert result == (verify.CERTIFIED if how[0] == 1 else verify.REFUTED)


def test_verification_object_spends_per_phase_and_refuses_without_a_phase():
    v = verify.Verification(0.8, DELTA)
    with pytest.raises(RuntimeError):
        v.record(True)
    v.start()
    assert v.level == pytest.approx(DELTA / 2)
    v.start()
    assert v.level == pytest.approx(DELTA / 6)
    with pytest.raises(ValueError):
        verify.log_evidence(1, 2, 1.0)


def test_replay_stops_where_the_bound_first_calls_for_a_test():
    # The bound reaches ρ at check 5 only; the truth is high from there on.
    runs, checks = 200, 10
    trig = _always(runs, checks, 0.0)
    trig[:, 5:] = 0.9
    truth = _always(runs, checks, 0.5)
    truth[:, 5:] = 0.97
    steps = 100 * np.arange(1, checks + 1)
    out = verify.simulate_stops(trig, truth, steps, 0.8, 3000, np.random.default_rng(6))
    assert out["stopped"].all()
    assert (out["stop_step"] > steps[5]).all()
    assert (out["truth"] == 0.97).all()
    assert (out["stop_step"] == steps[5] + out["attempts"]).all()


def test_replay_counts_the_attempts_after_a_failure_as_steps():
    # At tau = 0.8 a fifth of the test's attempts fail, and each failure costs
    # the attempts until the next success (the object toppled, not dropped): a
    # phase takes more steps than the test has samples.
    runs = 400
    steps = np.array([100])
    out = verify.simulate_stops(
        _always(runs, 1, 0.9), _always(runs, 1, 0.8), steps, 0.6, 3000,
        np.random.default_rng(7),
    )  # fmt: skip
    used, how, wins = verify._phase(
        np.full(runs, 0.8), np.full(runs, 2900), np.full(runs, DELTA / 2), 0.6,
        np.random.default_rng(7),
    )  # fmt: skip
    assert out["stopped"].mean() > 0.95
    samples, fails = used.mean(), (used - wins).mean()
    # each failure adds 1 / tau = 1.25 attempts on average (within 15 %)
    extra = out["attempts"].mean() - samples
    assert extra == pytest.approx(1.25 * fails, rel=0.15)


def test_verified_rows_of_the_analysis():
    # Checks of 300 runs: truth 0.9 everywhere, our bound 0.85 from step 300.
    rows = []
    for r in range(300):
        for step in range(100, 1100, 100):
            rows.append(
                dict(object="a", trial=0, rollout=r, step=step,
                     p_lower_eb=0.85 if step >= 300 else 0.1, true_performance=0.9)
            )  # fmt: skip
    checks = pd.DataFrame(rows)
    sens = an.verified_stopping(checks, [0.5, 0.8, 0.95], horizon=1000)
    assert list(sens["bound"]) == [an.VERIFIED] * 3
    at = sens.set_index("rho_min")
    assert at.loc[0.5, "accuracy"] == 1.0 and at.loc[0.8, "accuracy"] == 1.0
    assert at.loc[0.5, "n_stopped"] == 300
    # no test starts where the bound stays below the threshold
    assert at.loc[0.95, "n_stopped"] == 0 and at.loc[0.95, "mean_stop_step"] == 1000
    assert (sens["mean_stop_step"] > 300).all()
    # reproducible: the same rows again
    pd.testing.assert_frame_equal(
        sens, an.verified_stopping(checks, [0.5, 0.8, 0.95], horizon=1000)
    )


# ------------------------------------------------- the engine's recorded cost


def _tables(p, topple, landing):
    from types import SimpleNamespace

    import jax.numpy as jnp

    return SimpleNamespace(
        p=jnp.asarray(p, jnp.float32)[None],
        topple_cdf=jnp.asarray(np.cumsum(topple, -1), jnp.float32)[None],
        landing=jnp.asarray(landing, jnp.float32)[None],
    )


def test_attempts_after_a_failure_match_a_simulated_chain():
    # Three poses; the recommended grasps succeed with 0.9, 0.4 and 0.7; a failure
    # topples the object by the rows of T. Simulated directly: land (λ), fail,
    # then count the attempts until a success.
    import jax.numpy as jnp

    from legs_jax.core import engine

    p = np.array([[0.9, 0.2], [0.1, 0.4], [0.7, 0.0]])  # [P, K]
    rec = np.array([0, 1, 0])
    T = np.array([[0.6, 0.3, 0.1], [0.2, 0.5, 0.3], [0.0, 0.5, 0.5]])
    lam = np.array([0.5, 0.3, 0.2])
    got = float(
        engine._after_failure(_tables(p, T, lam), jnp.array([0]), jnp.array([rec]))[0]
    )
    rng = np.random.default_rng(0)
    ps = p[np.arange(3), rec]
    n = 200_000  # landings, simulated side by side
    s = rng.choice(3, size=n, p=lam)
    failed = rng.random(n) >= ps[s]
    s = s[failed]  # a failure at the landing: count the attempts after it
    counts = np.zeros(s.size, np.int64)
    live = np.ones(s.size, bool)
    cum = np.cumsum(T, axis=1)
    while live.any():
        i = np.flatnonzero(live)
        s[i] = (rng.random(i.size)[:, None] > cum[s[i]]).sum(1)  # topple
        counts[i] += 1
        live[i] = rng.random(i.size) >= ps[s[i]]
    se = counts.std() / math.sqrt(len(counts))
    assert got == pytest.approx(counts.mean(), abs=4 * se)


def test_attempts_after_a_failure_edge_cases():
    import jax.numpy as jnp

    from legs_jax.core import engine

    T = np.array([[0.0, 1.0], [0.0, 1.0]])
    # every frozen grasp succeeds: no failure, nothing after one
    sure = _tables([[1.0], [1.0]], T, [0.5, 0.5])
    assert (
        float(engine._after_failure(sure, jnp.array([0]), jnp.array([[0, 0]]))[0]) == 0
    )
    # a failure leads to a pose that is never left (p = 0, topples onto itself)
    stuck = _tables([[0.5], [0.0]], T, [1.0, 0.0])
    out = engine._after_failure(stuck, jnp.array([0]), jnp.array([[0, 0]]))
    assert np.isinf(float(out[0]))


def test_replay_uses_the_recorded_attempts_after_a_failure():
    runs = 300
    steps = np.array([100])
    after = np.full((runs, 1), 2.5)
    out = verify.simulate_stops(
        _always(runs, 1, 0.9), _always(runs, 1, 0.8), steps, 0.6, 3000,
        np.random.default_rng(7), after=after,
    )  # fmt: skip
    used, how, wins = _phases(0.8, 0.6, runs, 7, budget=2900)
    ok = how == 1
    assert out["stopped"].tolist() == ok.tolist()
    np.testing.assert_allclose(
        out["stop_step"][ok], 100 + used[ok] + 2.5 * (used - wins)[ok]
    )
