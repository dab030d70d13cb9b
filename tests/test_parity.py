"""Parity of the JAX engine with the NumPy reference (legs_jax.core.reference).

The two draw their random numbers differently (JAX keys vs NumPy generators), so
stochastic results are compared in distribution: 256 engine rollouts against 200
reference rollouts per method on the same synthetic problem, with fixed seeds, by
two-sample tests at level 1e-3 (Kolmogorov–Smirnov on the final gap, Welch's t on
the means of the final gap, the success rate, the distinct grasps tried, the
replacements and the last Dirichlet check). Deterministic pieces agree exactly:
the constant rows' gaps; the LEGS pruning step is in ``test_methods.py``.

The engine side runs the same compiled programs as the conformance tests.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from test_methods import (
    CFG_KN,
    ODD,
    RUN,
    conformance_problem,
    own,
    shared_run,
    shared_run_params,
)

from legs_jax.core import engine, methods
from legs_jax.core import reference as ref

ALPHA = 1e-3  # level of every two-sample test
R_REF = 100  # reference rollouts per trial (2 trials: 200)


@functools.cache
def _problem():
    return conformance_problem()


@functools.cache
def engine_result(name: str) -> dict[str, np.ndarray]:
    """256 engine rollouts with the default hyperparameters: grid points 0 and 1
    of the conformance run."""
    out = {k: v[:2].reshape((-1,) + v.shape[2:]) for k, v in shared_run(name).items()}
    out["trial"] = out["ot"]
    return out


@functools.cache
def reference_result(name: str) -> dict[str, np.ndarray]:
    r = ref.run(
        _problem(), name, trials=[0, 1], num_rollouts=R_REF,
        hparams=own(name, **CFG_KN), seed=0,
        horizon=RUN["horizon"], record_every=RUN["record_every"],
        check_every=RUN["check_every"],
    )  # fmt: skip
    out = {f: np.asarray(getattr(r, f)) for f in r._fields if getattr(r, f) is not None}
    flat = {}
    for k, v in out.items():
        flat[k] = v.reshape((-1,) + v.shape[4:]) if v.ndim >= 4 else v
    flat["trial"] = np.repeat([0, 1], R_REF)
    return flat


def _ks(a, b) -> float:
    """Two-sample KS p-value of two samples brought to one representation.

    Final gaps take a few values many times (one per grasp the recommendation can
    end on); the engine computes them in float32 and the reference in float64, so
    the same atom sits at two values one float32 ulp apart, which alone makes the
    empirical CDFs differ by the atom's mass. Both sides are rounded to 1e-6 in
    float64 first (far below any difference between two grasps' gaps).
    """
    a = np.round(np.asarray(a, np.float64), 6)
    b = np.round(np.asarray(b, np.float64), 6)
    return stats.ks_2samp(a, b).pvalue


def _welch(a, b, what):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if np.ptp(a) == 0 and np.ptp(b) == 0:
        assert a[0] == pytest.approx(b[0], abs=1e-5), what
        return
    p = stats.ttest_ind(a, b, equal_var=False).pvalue
    assert p > ALPHA, f"{what}: means {a.mean():.4g} vs {b.mean():.4g}, p = {p:.2g}"


# Every registered method that learns and has a NumPy twin.
LEARNERS = tuple(
    n
    for n in methods.names()
    if methods.get(n).learns and methods.get(n).card.reference
)


@pytest.mark.parametrize("name", shared_run_params(LEARNERS))
def test_parity_in_distribution(name):
    e, r = engine_result(name), reference_result(name)
    assert e["final_gap"].size >= 200 and r["final_gap"].size >= 200
    p = _ks(e["final_gap"], r["final_gap"])
    assert p > ALPHA, f"final gap distributions differ (KS p = {p:.2g})"
    _welch(e["final_gap"], r["final_gap"], "final gap")
    _welch(
        e["successes"] / RUN["horizon"], r["successes"] / RUN["horizon"], "success rate"
    )
    _welch(e["distinct_grasps"], r["distinct_grasps"], "distinct grasps")
    _welch(e["replacements"], r["replacements"], "replacements")
    # the learning curve half-way
    mid = RUN["horizon"] // 2 // RUN["record_every"]
    _welch(e["gaps"][:, mid], r["gap_curve"][:, mid], "gap at H/2")
    # the last Dirichlet check, both variants, and the true performance beside it
    _welch(e["check_p_lower"][:, -1], r["check_p_lower"][:, -1], "p_lower")
    _welch(
        e["check_p_lower_attempted"][:, -1],
        r["check_p_lower_attempted"][:, -1],
        "p_lower (attempted)",
    )
    _welch(
        e["check_true_performance"][:, -1],
        r["check_true_performance"][:, -1],
        "true performance",
    )


@pytest.mark.parametrize("name", shared_run_params(["dexnet", "k100_ub"]))
def test_constant_rows_exact(name):
    """Dex-Net and the K100 upper bound: the same constant gap as the reference at
    every recorded step, and the environment statistics in distribution."""
    e, r = engine_result(name), reference_result(name)
    for trial in (0, 1):
        want = ref.constant_gap(_problem(), name, trial)
        got = e["gaps"][e["trial"] == trial]
        np.testing.assert_allclose(got, want, atol=2e-6)
        np.testing.assert_allclose(r["gap_curve"][r["trial"] == trial], want, atol=1e-9)
    _welch(e["successes"], r["successes"], "successes")
    _welch(e["check_p_lower"][:, -1], r["check_p_lower"][:, -1], "p_lower")


@pytest.mark.xdist_group("shared-run-borges_100")
def test_borges_100_never_below_k100_upper_bound():
    """BORGES (K=100) recommends within the top-100 by q, so at every recorded step
    its gap is at least the K100 upper bound's (the paper, Section 5)."""
    b, k = shared_run("borges_100"), shared_run("k100_ub")  # all 3 grid points
    for trial in (0, 1):
        bound = k["gaps"][k["ot"] == trial]
        assert np.ptp(bound) == 0
        assert np.all(b["gaps"][b["ot"] == trial] >= bound[0, 0] - 1e-6)
    # the bound is reached by some rollouts (it is tight, not vacuous)
    assert np.any(np.abs(b["final_gap"] - k["final_gap"]) < 1e-6)


def test_dirichlet_bound_in_distribution():
    """The engine's Dirichlet bound from given counts agrees with the reference's
    (NumPy's Dirichlet sampler) in distribution over 400 draws of each."""
    counts = np.array([40, 0, 7, 2, 0], np.float32)
    observed = np.array([True, False, True, True, True])
    values = np.array([0.9, 0.5, 0.2, 0.6, 0.0], np.float32)
    n = 400
    ks = jax.random.split(jax.random.key(4), n)
    bound = jax.jit(engine.dirichlet_quantiles, static_argnums=(4, 5))
    got = np.asarray(
        bound(
            ks, jnp.tile(counts, (n, 1)), jnp.tile(observed, (n, 1)),
            jnp.tile(values, (n, 1, 1)), 0.05, 3000,
        )[:, 0]
    )  # fmt: skip
    rng = np.random.default_rng(5)
    want = np.array(
        [
            ref.dirichlet_lower_bound(counts, observed, values, 0.05, 3000, rng)
            for _ in range(n)
        ]
    )
    _welch(got, want, "Dirichlet bound")
    assert stats.ks_2samp(got, want).pvalue > ALPHA


@pytest.mark.slow
@pytest.mark.parametrize("name", shared_run_params(LEARNERS))
def test_parity_unusual_hyperparameters(name):
    """Grid point 2 of the conformance run (the original BORGES prior,
    prior_offset = 0 and s = 5, with δ = 0.2, γ = 0.5, ε = 0.5, η = 0.3): 128 engine
    rollouts against 128 reference rollouts."""
    e = {k: v[2] for k, v in shared_run(name).items()}
    r = ref.run(
        _problem(), name, trials=[0, 1], num_rollouts=64,
        hparams=own(name, **CFG_KN, **ODD),
        seed=1, horizon=RUN["horizon"], record_every=RUN["record_every"],
        check_every=RUN["check_every"],
    )  # fmt: skip
    r = {f: np.asarray(getattr(r, f)).reshape(-1) for f in ("final_gap", "successes",
         "distinct_grasps", "replacements")}  # fmt: skip
    assert _ks(e["final_gap"], r["final_gap"]) > ALPHA
    for f in ("final_gap", "successes", "distinct_grasps", "replacements"):
        _welch(e[f], r[f], f)
