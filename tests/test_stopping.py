"""Our stopping bound (legs_jax.core.stopping): the exact posterior pieces, and its
coverage on synthetic problems where its model is true."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy import stats

from legs_jax.core import engine, stopping
from legs_jax.errors import ConfigError

# ------------------------------------------------------------------ the pieces


def _em(lik, w):
    for _ in range(stopping.EM_ITERATIONS):
        r = w * lik
        w = (r / r.sum(1, keepdims=True)).mean(0)
    return w


def _pooled_start(succ, fail):
    """The pooled start: the bin of the pooled success rate at 1, the others at
    START_FLOOR, normalised."""
    j = min(int(succ.sum() / (succ + fail).sum() * stopping.GRID), stopping.GRID - 1)
    w = np.full(stopping.GRID, stopping.START_FLOOR)
    w[j] = 1.0
    return w / w.sum()


def test_eb_posterior_is_the_prior_reweighted_by_the_grasps_likelihood():
    # One pose, every grasp tried: the fit is EM over the other grasps (the
    # recommended one left out, the default) from the pooled start, and the
    # rec's posterior is that prior times its Binomial likelihood at the bin
    # centres.
    rng = np.random.default_rng(0)
    succ = rng.integers(0, 6, (1, 1, 40)).astype(np.float32)
    fail = rng.integers(0, 6, (1, 1, 40)).astype(np.float32)
    fit = np.ones((1, 1, 40), bool)
    rec = np.zeros((1, 1, 40), bool)
    rec[0, 0, 7] = True
    theta = (np.arange(stopping.GRID) + 0.5) / stopping.GRID
    lik = stats.binom.pmf(succ[0, 0, :, None], (succ + fail)[0, 0, :, None], theta)
    others = np.arange(40) != 7
    start = _pooled_start(succ[0, 0, others], fail[0, 0, others])
    for kw, w0, rows in (
        ({}, start, others),
        ({"start": "uniform"}, np.full(stopping.GRID, 1 / stopping.GRID), others),
        # leave_out_rec=False (the first design): all 40 grasps shape G_s
        (
            {"leave_out_rec": False, "start": "uniform"},
            np.full(stopping.GRID, 1 / stopping.GRID),
            slice(None),
        ),
    ):
        post = np.asarray(stopping.eb_posterior(succ, fail, fit, rec, **kw))[0, 0]
        want = _em(lik[rows], w0) * lik[7]
        np.testing.assert_allclose(post, want / want.sum(), atol=2e-5, err_msg=kw)
    with pytest.raises(ValueError, match="start must be one of"):
        stopping.eb_posterior(succ, fail, fit, rec, start="wide")


def test_the_pooled_start_shrinks_where_the_outcomes_cannot_tell_the_spread():
    """Every grasp of the pose succeeds with p = 0.3, and all but the
    recommended one were tried once: those outcomes tell only the pose's mean
    rate. From the pooled start the fit stays at it, and the recommended grasp's
    3 successes in 3 tries (its luck: its p is 0.3 too) are shrunk to about the
    truth; from the uniform start the fit stays wide and the posterior keeps
    most of that luck (the winner's curse)."""
    rng = np.random.default_rng(4)
    n = 80
    succ = (rng.random((1, 1, n)) < 0.3).astype(np.float32)
    fail = 1.0 - succ
    succ[..., 0], fail[..., 0] = 3.0, 0.0  # the recommended grasp
    fit = np.ones(succ.shape, bool)
    rec = np.arange(n)[None, None] == 0
    theta = (np.arange(stopping.GRID) + 0.5) / stopping.GRID
    mean = {
        start: float(
            np.asarray(stopping.eb_posterior(succ, fail, fit, rec, start=start))[0, 0]
            @ theta
        )
        for start in stopping.FIT_STARTS
    }
    assert abs(mean["pooled"] - 0.3) < 0.05
    assert mean["uniform"] > 0.3 + 0.2


def test_forgotten_grasps_enter_the_fit_like_kept_ones():
    rng = np.random.default_rng(1)
    succ = rng.integers(0, stopping.CAP, (2, 3, 30)).astype(np.float32)
    fail = rng.integers(0, stopping.CAP, (2, 3, 30)).astype(np.float32)
    fit = np.ones(succ.shape, bool)
    rec = np.zeros(succ.shape, bool)
    rec[..., 0] = True
    whole = np.asarray(stopping.eb_posterior(succ, fail, fit, rec))
    # the last 20 columns forgotten (a prune replaced their grasps)
    ids = np.broadcast_to(np.arange(30), succ.shape)
    after_ids = np.where(np.arange(30) >= 10, ids + 100, ids)
    after_fit = np.arange(30) < 10
    lost = stopping.forgotten_cells(
        (succ, fail, fit, ids),
        (succ, fail, np.broadcast_to(after_fit, fit.shape), after_ids),
    )
    assert np.asarray(lost).sum() == 2 * 3 * 20
    kept = np.asarray(stopping.eb_posterior(succ, fail, fit & after_fit, rec, lost))
    np.testing.assert_allclose(kept, whole, atol=1e-5)
    # a dense method keeps its pruned grasps: nothing is forgotten
    same = stopping.forgotten_cells((succ, fail, fit, ids), (succ, fail, fit, ids))
    assert np.asarray(same).sum() == 0


def test_leave_out_fits_the_prior_without_the_recommended_grasp():
    """leave_out_rec (the default): G_s is fitted to the other grasps only,
    and the recommended grasp's own likelihood still weighs its posterior."""
    rng = np.random.default_rng(2)
    succ = rng.integers(0, 6, (2, 3, 20)).astype(np.float32)
    fail = rng.integers(0, 6, (2, 3, 20)).astype(np.float32)
    fit = rng.random(succ.shape) < 0.8
    rec = np.zeros(succ.shape, bool)
    rec[..., 4] = True
    fit[..., 4] = True
    out = np.asarray(stopping.eb_posterior(succ, fail, fit, rec))
    # the recommended grasp's outcomes changed: the fit of G_s does not move
    more = succ.copy()
    more[..., 4] += 30
    moved = np.asarray(stopping.eb_posterior(more, fail, fit, rec))
    none = np.zeros_like(rec)  # no recommendation: the posterior is G_s itself
    prior = np.asarray(stopping.eb_posterior(succ, fail, fit & ~rec, none))
    theta = (np.arange(stopping.GRID) + 0.5) / stopping.GRID
    for post, s in ((out, succ), (moved, more)):
        lik = theta ** s[..., 4:5] * (1 - theta) ** fail[..., 4:5]
        want = prior * lik
        np.testing.assert_allclose(post, want / want.sum(-1, keepdims=True), atol=2e-5)
    # leave_out_rec=False: the recommended grasp's own outcomes also shape G_s
    with_rec = stopping.eb_posterior(succ, fail, fit, rec, leave_out_rec=False)
    with_rec = np.asarray(with_rec)
    assert np.abs(with_rec - out).max() > 1e-3


def test_a_pose_without_attempts_gets_the_uniform_prior():
    z = np.zeros((1, 2, 5), np.float32)
    post = np.asarray(stopping.eb_posterior(z, z, z > 0, z > 0))
    np.testing.assert_allclose(post, 1 / stopping.GRID, rtol=1e-6)


def _draws_by_reductions(keys, post, num_samples):
    """draw_values as first written: the bin search by reductions over a
    trailing J axis of [B, M, P, J] (the draws must not change by a bit)."""
    import jax.numpy as jnp

    B, P, J = post.shape

    def row(k):
        k = jax.random.fold_in(k, stopping.UNIFORM_STREAM)
        return jax.vmap(
            lambda s: jax.random.uniform(jax.random.fold_in(k, s), (num_samples,))
        )(jnp.arange(P))

    u = jnp.swapaxes(jax.vmap(row)(keys), 1, 2)  # [B, M, P]
    cdf = jnp.cumsum(post, axis=-1)[:, None]
    below = cdf <= u[..., None]
    j = jnp.minimum(jnp.sum(below, axis=-1), J - 1)
    before = jnp.max(jnp.where(below, cdf, 0.0), axis=-1)
    upto = jnp.min(jnp.where(below, jnp.inf, cdf), axis=-1)
    wj = jnp.where(jnp.isfinite(upto), upto - before, 1.0)
    frac = jnp.clip((u - before) / jnp.maximum(wj, 1e-30), 0.0, 1.0)
    return (j.astype(jnp.float32) + frac) / J


def test_draws_are_bit_identical_to_the_bin_search_by_reductions():
    rng = np.random.default_rng(3)
    for i, (B, P, M) in enumerate([(7, 5, 300), (1, 1, 1), (3, 12, 64)]):
        post = rng.dirichlet(np.full(stopping.GRID, [0.05, 1.0, 10.0][i]), (B, P))
        post = post.astype(np.float32)
        post[0, 0] = 0.0
        # one bin, zeros around it (in the upper half, which the next line keeps
        # when the first and last rows are the same)
        post[0, 0, rng.integers(stopping.GRID // 2, stopping.GRID)] = 1.0
        post[-1, -1, : stopping.GRID // 2] = 0.0  # empty bins first
        post[-1, -1] /= post[-1, -1].sum()
        keys = jax.random.split(jax.random.key(i), B)
        got = np.asarray(jax.jit(stopping.draw_values, static_argnums=2)(keys, post, M))
        want = np.asarray(
            jax.jit(_draws_by_reductions, static_argnums=2)(keys, post, M)
        )
        assert got.shape == (B, M, P)
        assert got.tobytes() == want.tobytes()


def test_draws_follow_the_histogram_posterior():
    post = np.zeros((1, 1, stopping.GRID), np.float32)
    post[0, 0, [3, 12]] = [0.25, 0.75]
    x = np.asarray(
        stopping.draw_values(jax.random.split(jax.random.key(1), 1), post, 20000)
    )
    x = x[0, :, 0]
    lo3, lo12 = 3 / stopping.GRID, 12 / stopping.GRID
    in3 = (x >= lo3) & (x < lo3 + 1 / stopping.GRID)
    in12 = (x >= lo12) & (x < lo12 + 1 / stopping.GRID)
    assert np.all(in3 | in12)
    # share in bin 3: binomial(20000, 0.25), 4 standard deviations
    assert abs(in3.mean() - 0.25) < 4 * np.sqrt(0.25 * 0.75 / 20000)
    # uniform inside a bin: Kolmogorov-Smirnov at 1 %
    u = (x[in12] - lo12) * stopping.GRID
    assert stats.kstest(u, "uniform").pvalue > 0.01


# ------------------------------------------------------------------- coverage


def _synthetic_checks(n_problems: int, seed: int):
    """Problems drawn from the bound's model: λ ~ Dir(1, ..., 1) over P poses,
    the p of each pose's N grasps i.i.d. from one mixture G (a share of good
    grasps among poor ones, drawn per pose); D drops land by λ, and each landing
    buys A Thompson-sampling attempts (uniform Beta prior) in its pose; the
    recommendation is the largest posterior mean (the paper's plug-in)."""
    rng = np.random.default_rng(seed)
    B, P, N, D, A = n_problems, 4, 100, 40, 6
    lam = rng.dirichlet(np.ones(P), B)
    good = rng.uniform(0.05, 0.4, (B, P, 1))
    is_good = rng.random((B, P, N)) < good
    p = np.where(is_good, rng.beta(12, 2, (B, P, N)), rng.beta(2, 5, (B, P, N)))
    counts = np.zeros((B, P))
    succ = np.zeros((B, P, N))
    fail = np.zeros((B, P, N))
    bi = np.arange(B)
    for _ in range(D):
        s = (rng.random((B, 1)) > np.cumsum(lam, 1)).sum(1)
        counts[bi, s] += 1
        for _ in range(A):
            phi = rng.beta(1 + succ[bi, s], 1 + fail[bi, s])
            a = phi.argmax(1)
            r = rng.random(B) < p[bi, s, a]
            succ[bi, s, a] += r
            fail[bi, s, a] += ~r
    mean = (1 + succ) / (2 + succ + fail)
    rec = mean.argmax(-1)  # [B, P]
    observed = counts > 0
    truth = (lam * np.take_along_axis(p, rec[..., None], -1)[..., 0]).sum(1)
    plug_in = np.take_along_axis(mean, rec[..., None], -1)[..., 0]
    return counts, observed, succ, fail, rec, plug_in, truth


@pytest.mark.parametrize(
    "leave_out_rec, start", [(False, "uniform"), (True, "uniform"), (True, "pooled")]
)
def test_miss_rate_is_at_most_delta_stop_where_the_model_holds(leave_out_rec, start):
    """The shipped fit (without the recommended grasp's outcomes, from the pooled
    rate) and the two earlier ones (experiments/early_stopping/bound_design.py)."""
    n = 400
    counts, observed, succ, fail, rec, plug_in, truth = _synthetic_checks(n, 23)
    N = succ.shape[-1]
    post = stopping.eb_posterior(
        succ.astype(np.float32),
        fail.astype(np.float32),
        (succ + fail) > 0,
        rec[..., None] == np.arange(N),
        leave_out_rec=leave_out_rec,
        start=start,
    )
    keys = jax.random.split(jax.random.key(5), n)
    draws = stopping.draw_values(keys, post, engine.NUM_EB_SAMPLES)
    lo = np.asarray(
        engine.dirichlet_quantiles(
            keys,
            counts.astype(np.float32),
            observed,
            plug_in[:, None, :].astype(np.float32),
            draws=draws,
        )
    )
    paper, ours = lo[:, 0], lo[:, 1]
    # Binomial tolerance: the miss rate of n independent problems exceeds
    # δ_stop by at most 3 standard deviations of a Binomial(n, δ_stop) share.
    tol = 3 * np.sqrt(engine.DELTA_STOP * (1 - engine.DELTA_STOP) / n)
    miss = np.mean(ours > truth)
    assert miss <= engine.DELTA_STOP + tol, (miss, tol)
    # ... and it is no trivial bound (about 40 drops and 240 attempts over four
    # poses, unseen poses counted 0): within 0.25 of the truth on average, 0.35
    # from the pooled start, which pays for its validity on hard objects where a
    # pose's few good grasps stand apart from the rest, as here (good grasps are
    # 5 to 40 % of a pose)
    assert np.mean(truth - ours) < (0.35 if start == "pooled" else 0.25)
    # The same test catches the plug-in bound (the winner's curse).
    assert np.mean(paper > truth) > engine.DELTA_STOP + tol


def test_bound_design_scores_checks_and_refuses_bad_sizes(capsys):
    """The design study's checks, scored by the report's functions (valid: bound
    at most the truth), and its command line's refusal of an empty run."""
    from experiments.early_stopping import bound_design
    from legs_jax.report import analysis as an

    steps = np.array([100, 200, 300])
    one = bound_design.checks_frame("a", [[0.5, 0.7, 0.9]], [[0.6, 0.6, 0.9]], steps)
    got = an.bound_summary(one).iloc[0]
    assert (got["accuracy"], got["n_checks"]) == (2 / 3, 3)
    assert got["tightness"] == pytest.approx(0.0 / 3)
    # two runs of three checks (steps 100, 200, 300), H = 300: the first
    # reaches 0.8 at its second check, where its truth is 0.85 (right); the
    # second at its third, truth 0.7 (wrong); at 0.9 neither stops
    bound = np.array([[0.5, 0.8, 0.9], [0.1, 0.2, 0.8]])
    truth = np.array([[0.9, 0.85, 0.95], [0.9, 0.9, 0.7]])
    runs = bound_design.checks_frame("a", bound, truth, steps)
    sens = an.stopping_sensitivity(runs, [0.8, 0.95], 300).set_index("rho_min")
    r = sens.loc[0.8]
    assert (r["n_stopped"], r["accuracy"], r["mean_stop_step"]) == (2, 0.5, 250.0)
    r = sens.loc[0.95]
    assert (r["n_stopped"], r["mean_stop_step"]) == (0, 300.0)
    assert np.isnan(r["accuracy"])
    with pytest.raises(SystemExit) as e:
        bound_design.main(["--rollouts", "0"])
    assert e.value.code == 2
    assert "--rollouts must be at least 1" in capsys.readouterr().err
    # the variants: the three designs by name, the bootstrap as boot-R
    assert bound_design.variant("pooled") == (True, "pooled", 0)
    assert bound_design.variant("boot-8") == (True, "pooled", 8)
    for bad in ("boot-0", "boot-", "boot-x", "wide"):
        with pytest.raises(ValueError, match="unknown variant"):
            bound_design.variant(bad)
    with pytest.raises(SystemExit) as e:
        bound_design.main(["--variants", "pooled,wide"])
    assert e.value.code == 2
    assert "unknown variant 'wide'" in capsys.readouterr().err


def _misspecified_checks(n, seed, poses, drops, tries, draw_p):
    """Problems outside the bound's histogram model's comfort: ``draw_p`` draws
    every grasp's p (skewed, bimodal, hard); ``drops`` landings by λ ~ Dir(1),
    ``tries`` Thompson attempts (uniform Beta prior) per landing over 100 grasps;
    the recommendation is the largest posterior mean."""
    rng = np.random.default_rng(seed)
    lam = rng.dirichlet(np.ones(poses), n)
    p = draw_p(rng, (n, poses, 100))
    counts = np.zeros((n, poses))
    succ = np.zeros(p.shape)
    fail = np.zeros(p.shape)
    bi = np.arange(n)
    for _ in range(drops):
        s = (rng.random((n, 1)) > np.cumsum(lam, 1)).sum(1).clip(0, poses - 1)
        counts[bi, s] += 1
        for _ in range(tries):
            a = rng.beta(1 + succ[bi, s], 1 + fail[bi, s]).argmax(1)
            r = rng.random(n) < p[bi, s, a]
            succ[bi, s, a] += r
            fail[bi, s, a] += ~r
    rec = ((1 + succ) / (2 + succ + fail)).argmax(-1)
    truth = (lam * np.take_along_axis(p, rec[..., None], -1)[..., 0]).sum(1)
    return counts, succ, fail, rec, truth


@pytest.mark.parametrize(
    "case",
    [
        # hard objects: every grasp poor, ten poses, two tries a landing
        (7, 10, 60, 2, lambda r, sh: r.beta(2, 6, sh)),
        # skewed: most grasps near 0, a long upper tail
        (8, 4, 40, 3, lambda r, sh: r.beta(1, 9, sh)),
        # bimodal: one grasp in ten good (0.9), the rest 0.05
        (9, 6, 40, 3, lambda r, sh: np.where(r.random(sh) < 0.1, 0.9, 0.05)),
    ],
    ids=["hard-many-poses", "skewed", "bimodal"],
)
def test_miss_rate_is_at_most_delta_stop_where_the_model_is_wrong(case):
    """The shipped bound where G_s is no histogram the fit can reach in few
    tries: misses at most δ_stop + 3 binomial standard deviations (400
    problems)."""
    n = 400
    counts, succ, fail, rec, truth = _misspecified_checks(n, *case)
    post = stopping.eb_posterior(
        succ.astype(np.float32), fail.astype(np.float32), (succ + fail) > 0,
        rec[..., None] == np.arange(succ.shape[-1]),
    )  # fmt: skip
    keys = jax.random.split(jax.random.key(5), n)
    draws = stopping.draw_values(keys, post, engine.NUM_EB_SAMPLES)
    values = np.zeros((n, 1, counts.shape[1]), np.float32)
    lo = engine.dirichlet_quantiles(
        keys, counts.astype(np.float32), counts > 0, values, draws=draws
    )
    ours = np.asarray(lo)[:, 1]
    tol = 3 * np.sqrt(engine.DELTA_STOP * (1 - engine.DELTA_STOP) / n)
    assert np.mean(ours > truth) <= engine.DELTA_STOP + tol


def test_ours_takes_the_first_samples_of_the_same_dirichlet_draws():
    """Our bound's quantile is over the first NUM_EB_SAMPLES of the M Dirichlet
    samples: computed beside the paper's bound or alone on M' samples it is the
    same bit for bit, and the paper's bound does not change with it."""
    n = 6
    counts, observed, succ, fail, rec, plug_in, _ = _synthetic_checks(n, 7)
    N = succ.shape[-1]
    post = stopping.eb_posterior(
        succ.astype(np.float32), fail.astype(np.float32), (succ + fail) > 0,
        rec[..., None] == np.arange(N),
    )  # fmt: skip
    keys = jax.random.split(jax.random.key(3), n)
    m2 = engine.NUM_EB_SAMPLES
    assert m2 < engine.NUM_DIRICHLET_SAMPLES
    draws = stopping.draw_values(keys, post, m2)
    c, v = counts.astype(np.float32), plug_in[:, None, :].astype(np.float32)
    both = np.asarray(engine.dirichlet_quantiles(keys, c, observed, v, draws=draws))
    paper = np.asarray(engine.dirichlet_quantiles(keys, c, observed, v))
    none = np.zeros((n, 0, c.shape[1]), np.float32)
    alone = np.asarray(
        engine.dirichlet_quantiles(
            keys, c, observed, none, engine.DELTA_STOP, m2, draws=draws
        )
    )
    assert both.shape == (n, 2) and alone.shape == (n, 1)
    np.testing.assert_array_equal(both[:, 0], paper[:, 0])
    np.testing.assert_array_equal(both[:, 1], alone[:, 0])
    with pytest.raises(ConfigError):
        engine.dirichlet_quantiles(keys, c, observed, v, engine.DELTA_STOP, m2 - 1,
                                   draws=draws)  # fmt: skip


# ------------------------------------------------- the bootstrap of G_s's fit


def _toy_counts(seed, shape=(2, 3, 30), cap=6):
    rng = np.random.default_rng(seed)
    succ = rng.integers(0, cap, shape).astype(np.float32)
    fail = rng.integers(0, cap, shape).astype(np.float32)
    rec = np.zeros(shape, bool)
    rec[..., 0] = True
    return succ, fail, np.ones(shape, bool), rec


def test_unit_weights_are_the_plug_in_fit():
    succ, fail, fit, rec = _toy_counts(11)
    plain = np.asarray(stopping.eb_posterior(succ, fail, fit, rec))
    ones = np.asarray(
        stopping.eb_posterior(succ, fail, fit, rec, weights=np.ones(succ.shape))
    )
    np.testing.assert_array_equal(ones, plain)
    # no replicates: the bootstrap is the plug-in fit, bit for bit
    keys = jax.random.split(jax.random.key(0), succ.shape[0])
    zero = stopping.bootstrap_posterior(keys, succ, fail, fit, rec, None, 0)
    np.testing.assert_array_equal(np.asarray(zero), plain)
    with pytest.raises(ValueError, match="at least 0"):
        stopping.bootstrap_posterior(keys, succ, fail, fit, rec, None, -1)
    # a weight of 2 is the grasp counted twice
    w = np.ones(succ.shape, np.float32)
    w[..., 5] = 2.0
    twice = (
        np.concatenate([succ, succ[..., 5:6]], -1),
        np.concatenate([fail, fail[..., 5:6]], -1),
    )
    dup = stopping.eb_posterior(
        *twice, np.ones(twice[0].shape, bool),
        np.concatenate([rec, np.zeros(rec[..., :1].shape, bool)], -1),
    )  # fmt: skip
    got = stopping.eb_posterior(succ, fail, fit, rec, weights=w)
    np.testing.assert_allclose(np.asarray(got), np.asarray(dup), atol=1e-5)


def test_bootstrap_is_deterministic_in_its_keys():
    succ, fail, fit, rec = _toy_counts(12)
    keys = jax.random.split(jax.random.key(0), 2)
    a = np.asarray(stopping.bootstrap_posterior(keys, succ, fail, fit, rec, None, 4))
    b = np.asarray(stopping.bootstrap_posterior(keys, succ, fail, fit, rec, None, 4))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a.sum(-1), 1.0, atol=1e-5)
    other = jax.random.split(jax.random.key(1), 2)
    c = np.asarray(stopping.bootstrap_posterior(other, succ, fail, fit, rec, None, 4))
    assert np.abs(a - c).max() > 1e-4
    # row b depends on keys[b] only
    swapped = np.asarray(
        stopping.bootstrap_posterior(
            keys[::-1], succ[::-1], fail[::-1], fit, rec, None, 4
        )  # fmt: skip
    )
    np.testing.assert_allclose(swapped[::-1], a, atol=1e-6)


def test_bootstrap_agrees_with_the_plug_in_where_the_fit_is_determined():
    """Thousands of grasps, many tries each, the recommended one in the bulk of
    G_s: every reweighting fits about the same G_s there, so the bootstrap's
    posterior is the plug-in's to within 0.02 a bin. (In G_s's tail, where a
    pose's best grasps are, a few grasps make each bin and the two differ: that
    is the uncertainty the bootstrap carries.)"""
    rng = np.random.default_rng(13)
    N = 4000
    p = rng.beta(2, 3, (1, 1, N))
    n = 60
    succ = rng.binomial(n, p).astype(np.float32)
    fail = n - succ
    rec = np.arange(N)[None, None] == int(np.argsort(succ[0, 0])[N // 2])
    fit = np.ones(succ.shape, bool)
    plug = np.asarray(stopping.eb_posterior(succ, fail, fit, rec))
    keys = jax.random.split(jax.random.key(2), 1)
    boot = stopping.bootstrap_posterior(keys, succ, fail, fit, rec, None, 16)
    boot = np.asarray(boot)
    np.testing.assert_allclose(boot, plug, atol=0.02)


def test_bootstrap_widens_the_posterior_where_the_fit_rests_on_few_grasps():
    """Eight grasps tried twice each, the recommended one 4 of 4: the fit of G_s
    is uncertain, and the bootstrap carries it: its lower 5 % quantile of the
    recommended grasp's p is below the plug-in's."""
    succ = np.array([[[4, 2, 1, 0, 2, 1, 0, 1]]], np.float32)
    fail = np.array([[[0, 0, 1, 2, 0, 1, 2, 1]]], np.float32)
    fit = np.ones(succ.shape, bool)
    rec = np.arange(8)[None, None] == 0
    theta = (np.arange(stopping.GRID) + 1.0) / stopping.GRID  # bin upper edges

    def q05(post):
        return theta[np.searchsorted(np.cumsum(np.asarray(post)[0, 0]), 0.05)]

    keys = jax.random.split(jax.random.key(4), 1)
    plug = stopping.eb_posterior(succ, fail, fit, rec)
    boot = stopping.bootstrap_posterior(keys, succ, fail, fit, rec, None, 256)
    assert q05(boot) < q05(plug)


def test_forgotten_cells_are_bootstrapped_like_their_grasps():
    """A forgotten cell of c grasps gets a Gamma(c, 1) weight, the law of the sum
    of its grasps' Exp(1) weights, so the bootstrap with 20 of 30 grasps forgotten
    has the mean of the one that kept them. 24 independent rows of 500 replicates
    each: every bin's mean over rows agrees within 4.5 standard errors (of the
    row means' spread; 4.5 keeps the 64 bins' joint false alarm below 1e-3)."""
    succ, fail, fit, rec = _toy_counts(14, (1, 2, 30), stopping.CAP)
    ids = np.broadcast_to(np.arange(30), succ.shape)
    after_fit = np.broadcast_to(np.arange(30) < 10, fit.shape)
    lost = stopping.forgotten_cells(
        (succ, fail, fit, ids),
        (succ, fail, after_fit, np.where(after_fit, ids, ids + 100)),
    )
    rows = 24

    def tile(x):
        return np.repeat(np.asarray(x), rows, axis=0)

    def boot(seed, fit_, lost_):
        keys = jax.random.split(jax.random.key(seed), rows)
        post = stopping.bootstrap_posterior(
            keys, tile(succ), tile(fail), tile(fit_), tile(rec), lost_, 500
        )
        post = np.asarray(post, np.float64)
        return post.mean(0), post.std(0, ddof=1) / np.sqrt(rows)

    whole, se_w = boot(6, fit, None)
    kept, se_k = boot(7, fit & after_fit, tile(lost))
    assert np.all(np.abs(kept - whole) <= 4.5 * np.hypot(se_w, se_k) + 1e-4)
    assert np.abs(kept - whole).max() < 0.02


@pytest.mark.slow
def test_bootstrap_miss_rate_is_at_most_delta_stop_where_the_model_holds():
    n = 400
    counts, observed, succ, fail, rec, plug_in, truth = _synthetic_checks(n, 23)
    keys = jax.random.split(jax.random.key(5), n)
    post = stopping.bootstrap_posterior(
        keys, succ.astype(np.float32), fail.astype(np.float32), (succ + fail) > 0,
        rec[..., None] == np.arange(succ.shape[-1]), None, 8,
    )  # fmt: skip
    draws = stopping.draw_values(keys, post, engine.NUM_EB_SAMPLES)
    values = np.zeros((n, 1, counts.shape[1]), np.float32)
    lo = engine.dirichlet_quantiles(
        keys, counts.astype(np.float32), observed, values, draws=draws
    )
    tol = 3 * np.sqrt(engine.DELTA_STOP * (1 - engine.DELTA_STOP) / n)
    assert np.mean(np.asarray(lo)[:, 1] > truth) <= engine.DELTA_STOP + tol
