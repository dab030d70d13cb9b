"""Statistical and exactness tests of legs_jax.core.sampling.

Kolmogorov-Smirnov tests use fixed seeds, so they are deterministic; the stated
significance level is the chance that an exact sampler would fail them with a fresh
seed.
"""

from __future__ import annotations

import jax
import jax.extend.random as jex_random
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special
import scipy.stats

from legs_jax.core import engine, sampling

# (alpha, beta) pairs: alpha = 1, shapes below 1 (prior_offset = 0), posterior-like
# shapes and large counts.
BETA_SHAPES = [
    (1.0, 1.0),
    (1.0, 2001.0),
    (2001.0, 1.0),
    (1.0, 3.7),
    (1.5, 1.5),
    (1.01, 1.99),
    (2.3, 7.1),
    (30.0, 50.0),
    (1.0 + 2000.0, 1.0 + 1000.0),
    (1.3 + 150.0, 1.7 + 2500.0),
    (0.5, 0.5),
    (0.05, 2.0),
    (0.2, 3.0),
    (3.0, 0.5),
    (0.01, 0.99),
    (0.3, 700.0),
    (5.0, 5.0),
]
# Family-wise significance: 17 tests at 1e-4 each, about 0.2 %.
KS_LEVEL = 1e-4


def _ks_pvalue(x: np.ndarray, dist, lo: float = 1e-30, hi: float = 1 - 1e-6) -> float:
    """KS p-value of float32 draws ``x`` against ``dist``, conditioned on (lo, hi).

    Float32 cannot represent draws below ~1e-38 (they underflow to 0) or resolve
    those within 6e-8 of 1 (they round onto a few grid points), which a KS test on
    the raw draws would flag for shapes below 1. The mass outside (lo, hi) is
    checked separately with a two-sided binomial test (same level).
    """
    x = np.asarray(x, np.float64).ravel()
    f_lo, f_hi = dist.cdf(lo), dist.cdf(hi)
    inside = x[(x > lo) & (x < hi)]
    conditional = lambda t: (dist.cdf(t) - f_lo) / (f_hi - f_lo)  # noqa: E731
    p_ks = scipy.stats.kstest(inside, conditional).pvalue
    p_in = scipy.stats.binomtest(len(inside), len(x), f_hi - f_lo).pvalue
    return min(p_ks, p_in)


def _keys(seed: int, n: int) -> jax.Array:
    return jax.random.split(jax.random.key(seed), n)


beta_rows = jax.jit(sampling.beta_rows)
gamma_rows = jax.jit(sampling.gamma_rows)


def test_threefry_matches_jax():
    rng = np.random.default_rng(0)
    key = rng.integers(0, 2**32, size=2, dtype=np.uint32)
    x = rng.integers(0, 2**32, size=(2, 1000), dtype=np.uint32)
    expected = np.asarray(jex_random.threefry_2x32(jnp.asarray(key), x.reshape(-1)))
    w0, w1 = sampling.threefry2x32(key[0], key[1], x[0], x[1])
    np.testing.assert_array_equal(np.concatenate([w0, w1]), expected)


def test_beta_ks_each_shape():
    """20 000 draws per (alpha, beta), one row each, KS against scipy.stats.beta."""
    a = np.array([s[0] for s in BETA_SHAPES], np.float32)
    b = np.array([s[1] for s in BETA_SHAPES], np.float32)
    n = 20_000
    x = np.asarray(
        beta_rows(
            _keys(1, len(a)), np.repeat(a[:, None], n, 1), np.repeat(b[:, None], n, 1)
        )
    )
    assert np.all((x >= 0) & (x <= 1))
    for row, (alpha, beta) in enumerate(BETA_SHAPES):
        p = _ks_pvalue(x[row], scipy.stats.beta(alpha, beta))
        assert p > KS_LEVEL, (alpha, beta, p)


def test_beta_ks_heterogeneous_rows():
    """Every element with its own shapes (as in a Thompson step): the probability
    integral transforms of 340 000 draws are uniform (KS, level 1e-3)."""
    rng = np.random.default_rng(2)
    shape = (len(BETA_SHAPES), 20_000)
    a = (1.0 + rng.uniform(0.01, 0.99, shape) + rng.poisson(3.0, shape)).astype(
        np.float32
    )
    b = (1.0 + rng.uniform(0.01, 0.99, shape) + rng.poisson(30.0, shape)).astype(
        np.float32
    )
    x = np.asarray(beta_rows(_keys(3, shape[0]), a, b))
    pit = scipy.stats.beta.cdf(x.astype(np.float64), a, b).ravel()
    assert scipy.stats.kstest(pit, "uniform").pvalue > 1e-3


@pytest.mark.parametrize("alpha", [0.1, 0.5, 1.0, 3.0, 2000.0])
def test_gamma_ks(alpha):
    x = np.asarray(gamma_rows(_keys(4, 4), np.full((4, 5000), alpha, np.float32)))
    assert np.all(np.isfinite(x)) and np.all(x >= 0)
    assert _ks_pvalue(x, scipy.stats.gamma(alpha), hi=np.inf) > KS_LEVEL


def test_retry_schedule_does_not_change_values():
    """An element keeps the first accepted try of its own sequence, so the size of
    the retry buffer (down to 1, forcing dozens of retry rounds) changes nothing."""
    k0, k1 = sampling.key_words(_keys(5, 3))
    a = jnp.full((3, 400), 1.0)  # the highest rejection rate, about 2.7 %
    counters = sampling._plain_counters(0)

    def draw(capacity):
        fn = jax.jit(
            lambda k0, k1, a: sampling._gamma_ge1(
                k0, k1, a, counters, capacity=capacity
            )
        )
        return np.asarray(fn(k0, k1, a))

    np.testing.assert_array_equal(draw(None), draw(1))


@pytest.mark.parametrize("boost", [False, True])
def test_beta_retry_schedule_does_not_change_values(boost):
    """A Beta element keeps the first accepted try of each of its gammas, so a
    retry buffer of 2 slots (dozens of rounds, later rounds redrawing more tries)
    gives the same bits as the default one."""
    k0, k1 = sampling.key_words(_keys(16, 3))
    a = np.full((3, 300), 1.0, np.float32)  # the highest rejection rate
    b = np.full((3, 300), 1.5, np.float32)
    if boost:
        a[:, ::7] = 0.3

    def draw(capacity):
        fn = jax.jit(
            lambda k0, k1, a, b: sampling._beta_rows(
                k0, k1, a, b, boost=boost, capacity=capacity
            )
        )
        return np.asarray(fn(k0, k1, a, b))

    default = draw(None)
    assert np.all((default >= 0) & (default <= 1))
    np.testing.assert_array_equal(default, draw(2))


@pytest.mark.parametrize(
    "total,rate,capacity",
    [
        (64_000, 0.03, 2048),
        (1000, 0.5, 64),
        (5000, 0.001, 256),
        (100, 0.0, 64),
        (33, 1.0, 64),
    ],
)
def test_pending_slots_are_the_first_true_entries(total, rate, capacity):
    """The packed slot search returns np.flatnonzero(mask)[:capacity], padded."""
    mask = np.random.default_rng(total).uniform(size=total) < rate
    _check_pending_slots([mask], capacity)


def _check_pending_slots(masks, capacity):
    """Each mask's slots are its first ``capacity`` True entries, padded with its
    size, and its count is its number of True entries (which may exceed the
    capacity)."""
    fn = jax.jit(lambda m: sampling._pending_slots(m, capacity, with_count=True))
    for mask in masks:
        got, count = (np.asarray(x) for x in fn(mask))
        want = np.flatnonzero(mask)[:capacity]
        want = np.concatenate([want, np.full(capacity - len(want), mask.size)])
        np.testing.assert_array_equal(got, want)
        assert int(count) == int(mask.sum())


@pytest.mark.parametrize("capacity", [2, 3, 64, 65])
def test_pending_slots_at_the_edges(capacity):
    """Slots are valid exactly up to the pending count, wherever the last pending
    entry falls: at the end of the last word or alone in it, a count equal to the
    capacity, one more, one less."""
    masks = [np.zeros(96, bool) for _ in range(7)]
    masks[0][-1] = True  # the last entry of the last word
    masks[1][64] = True  # alone, first in the last word
    masks[2][:] = True  # every entry
    masks[3][: capacity + 1] = True
    masks[4][:capacity] = True
    masks[5][: capacity - 1] = True
    masks[6][[0, 31, 32, 63]] = True  # word ends
    _check_pending_slots(masks, capacity)


def test_batch_invariance_bit_identical():
    """Row i depends only on keys[i], a[i], b[i]: a batch of 8, two batches of 4
    and 8 single rows give the same bits, with a row of shapes below 1 (which
    takes the boost path) mixed in."""
    rng = np.random.default_rng(6)
    keys = _keys(7, 8)
    a = (1.0 + rng.gamma(1.0, 20.0, (8, 1000))).astype(np.float32)
    b = (1.0 + rng.gamma(1.0, 20.0, (8, 1000))).astype(np.float32)
    a[5, :10] = 0.3  # row 5 needs the boost for shapes below 1
    whole = np.asarray(beta_rows(keys, a, b))
    halves = [
        np.asarray(beta_rows(keys[i : i + 4], a[i : i + 4], b[i : i + 4]))
        for i in (0, 4)
    ]
    singles = [
        np.asarray(beta_rows(keys[i : i + 1], a[i : i + 1], b[i : i + 1]))
        for i in range(8)
    ]
    np.testing.assert_array_equal(whole, np.concatenate(halves))
    np.testing.assert_array_equal(whole, np.concatenate(singles))
    # Different keys give different draws.
    assert len(np.unique(whole[:4, :100])) == 400


EXTREME_SHAPES = [
    (1e-6, 1e-6),
    (1e-3, 5.0),
    (0.0, 2.0),
    (1e6, 1e6),
    (1e6, 1.0),
    (1.0, 1e6),
    (1e-3, 1e6),
    (1e-30, 1e-30),
]


def test_beta_extreme_shapes_finite():
    a = np.array([s[0] for s in EXTREME_SHAPES], np.float32)
    b = np.array([s[1] for s in EXTREME_SHAPES], np.float32)
    x = np.asarray(
        beta_rows(
            _keys(9, 8), np.repeat(a[:, None], 1000, 1), np.repeat(b[:, None], 1000, 1)
        )
    )
    assert np.all(np.isfinite(x)) and np.all((x >= 0) & (x <= 1))
    for row, (alpha, beta) in enumerate(EXTREME_SHAPES):
        mean = alpha / (alpha + beta) if alpha > 0 else 0.0
        sd = np.sqrt(mean * (1 - mean) / (alpha + beta + 1))
        assert abs(x[row].mean() - mean) < 6 * sd / np.sqrt(1000) + 1e-6, (alpha, beta)


def test_uniform_rows():
    keys = _keys(10, 4)
    uniform_rows = jax.jit(sampling.uniform_rows, static_argnums=1)
    u = np.asarray(uniform_rows(keys, 5001))
    assert np.all((u > 0) & (u < 1))
    assert scipy.stats.kstest(u.ravel(), "uniform").pvalue > KS_LEVEL
    # A prefix of a longer draw is the shorter draw.
    np.testing.assert_array_equal(u[:, :100], np.asarray(uniform_rows(keys, 100)))
    bits = np.asarray(sampling.uniform_bits(keys, 64))
    assert bits.dtype == np.uint32 and len(np.unique(bits)) == bits.size


def test_key_words_rejects_bad_keys():
    with pytest.raises(ValueError, match="Threefry key"):
        sampling.key_words(jnp.zeros((3, 4), jnp.uint32))


PPF_SHAPES = [
    0.05,
    0.5,
    1.0,
    1.01,
    1.5,
    2.0,
    5.0,
    20.0,
    101.0,
    500.0,
    1001.0,
    2001.0,
    3001.0,
]
PPF_QS = [0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99]


# Every PPF call below has this many elements, so the tests share one compile.
_PPF_GRID = np.meshgrid(PPF_SHAPES, PPF_SHAPES, PPF_QS, indexing="ij")
PPF_N = _PPF_GRID[0].size + 6
beta_ppf = jax.jit(sampling.beta_ppf)


def test_beta_ppf_matches_scipy():
    a, b, q = (x.ravel() for x in _PPF_GRID)
    expected = scipy.stats.beta.ppf(q, a, b)
    # Edges ride along in the same call: q = 0 and 1, degenerate and huge shapes.
    edge_q = np.array([0.0, 1.0, 0.05, 0.05, 0.05, 0.95])
    edge_a = np.array([2.0, 2.0, 0.0, 1e-6, 1e6, 1e6])
    edge_b = np.array([3.0, 3.0, 1.0, 1.0, 1.0, 1e6])
    q_all = np.concatenate([q, edge_q]).astype(np.float32)
    a_all = np.concatenate([a, edge_a]).astype(np.float32)
    b_all = np.concatenate([b, edge_b]).astype(np.float32)
    got = np.asarray(beta_ppf(q_all, a_all, b_all))
    np.testing.assert_allclose(got[: len(q)], expected, rtol=0, atol=1e-4)
    edges = got[len(q) :]
    assert np.all(np.isfinite(edges))
    np.testing.assert_allclose(edges[:3], [0.0, 1.0, 0.0], atol=1e-20)
    np.testing.assert_allclose(
        edges[4:], scipy.stats.beta.ppf(edge_q[4:], edge_a[4:], edge_b[4:]), atol=1e-4
    )
    # An element's quantile does not depend on what else is in the call (small
    # shapes take the fixed-cost path, large ones the packed fallback).
    for i in np.linspace(0, PPF_N - 1, 9).astype(int):
        alone = beta_ppf(q_all[i : i + 1], a_all[i : i + 1], b_all[i : i + 1])
        assert np.asarray(alone)[0] == got[i], (a_all[i], b_all[i], q_all[i])


def test_beta_ppf_posterior_like_shapes():
    """Random Thompson posteriors 1 + s q + S, 1 + s (1 - q) + F at the bounds'
    quantiles delta and 1 - delta."""
    rng = np.random.default_rng(11)
    n = PPF_N
    q = rng.uniform(0.01, 0.99, n)
    s = rng.choice([0.0, 1.0, 5.0], n)
    wins = rng.integers(0, 2000, n) * (rng.uniform(size=n) < 0.5)
    losses = rng.integers(0, 3000, n) * (rng.uniform(size=n) < 0.5)
    a = (1 + s * q + wins).astype(np.float32)
    b = (1 + s * (1 - q) + losses).astype(np.float32)
    for delta in (0.01, 0.05, 0.2):
        for level in (delta, 1 - delta):
            got = np.asarray(beta_ppf(np.full(n, level, np.float32), a, b))
            expected = scipy.stats.beta.ppf(
                level, a.astype(np.float64), b.astype(np.float64)
            )
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4)


def test_betainc_matches_scipy():
    rng = np.random.default_rng(12)
    a = rng.choice(PPF_SHAPES, 20_000)
    b = rng.choice(PPF_SHAPES, 20_000)
    x = rng.uniform(0, 1, 20_000).astype(np.float32)
    got = np.asarray(
        jax.jit(sampling.betainc)(a.astype(np.float32), b.astype(np.float32), x)
    )
    expected = scipy.special.betainc(a, b, x.astype(np.float64))
    np.testing.assert_allclose(got, expected, rtol=0, atol=2e-5)


DIRICHLET_ROWS = 64
_quantiles = jax.jit(engine.dirichlet_quantiles, static_argnums=(4, 5))


def dirichlet_lower_bound(keys, counts, observed, values, delta: float):
    """The engine's bound (:func:`engine.dirichlet_quantiles`), one value vector
    a row, M = 3000."""
    v = jnp.asarray(values, jnp.float32)[:, None, :]
    args = (jnp.asarray(counts, jnp.float32), jnp.asarray(observed), v)
    return _quantiles(keys, *args, float(delta), 3000)[:, 0]


def test_dirichlet_lower_bound_against_numpy_monte_carlo():
    """64 independent bounds (M = 3000 each) against the delta-quantile of 2e6
    NumPy Dirichlet draws: their mean lies within 4 standard errors."""
    counts = np.array([5, 0, 20, 3, 7, 0], np.float32)
    observed = np.array([True, False, True, True, True, False])
    values = np.array([0.9, 0.5, 0.4, 0.7, 0.2, 0.3], np.float32)
    delta = 0.05
    alpha = np.concatenate([counts[observed] + 1, [1.0]])
    v = np.concatenate([values[observed], [0.0]])
    lam = np.random.default_rng(13).dirichlet(alpha, size=2_000_000)
    expected = np.quantile(lam @ v, delta)

    rows = DIRICHLET_ROWS
    got = np.asarray(
        dirichlet_lower_bound(
            _keys(14, rows),
            np.tile(counts, (rows, 1)),
            np.tile(observed, (rows, 1)),
            np.tile(values, (rows, 1)),
            delta,
        )
    )
    se = got.std(ddof=1) / np.sqrt(rows)
    assert abs(got.mean() - expected) < 4 * se
    # The spread of one bound matches the asymptotic sd of a sample quantile.
    density = scipy.stats.gaussian_kde(lam[:200_000] @ v)(expected)[0]
    sd = np.sqrt(delta * (1 - delta) / 3000) / density
    assert 0.6 < got.std(ddof=1) / sd < 1.6


def test_dirichlet_lower_bound_edges():
    rows = DIRICHLET_ROWS
    counts = np.zeros((rows, 6), np.float32)
    counts[:, :2] = [4, 2]
    observed = np.zeros((rows, 6), bool)
    observed[:, :2] = True
    observed[2] = False  # nothing observed: p' = 0
    values = np.ones((rows, 6), np.float32)
    values[1] = 0.0  # every value 0: p' = 0
    got = np.array(
        dirichlet_lower_bound(_keys(15, rows), counts, observed, values, 0.05)
    )
    median = dirichlet_lower_bound(_keys(15, rows), counts, observed, values, 0.5)
    got[3] = np.asarray(median)[3]
    # All observed mass has value 1: p' = 1 - lambda_unseen, lambda_unseen ~ Beta(1, 8).
    np.testing.assert_allclose(got[0], 1 - scipy.stats.beta.ppf(0.95, 1, 8), atol=0.02)
    np.testing.assert_allclose(got[3], 1 - scipy.stats.beta.ppf(0.5, 1, 8), atol=0.02)
    assert got[1] == 0.0 and got[2] == 0.0


def test_argmax_first():
    rng = np.random.default_rng(16)
    x = rng.integers(0, 4, size=(50, 37)).astype(np.float32)  # many ties
    np.testing.assert_array_equal(
        np.asarray(sampling.argmax_first(x)), np.argmax(x, axis=-1)
    )
    np.testing.assert_array_equal(
        np.asarray(sampling.argmax_first(x, axis=0)), np.argmax(x, axis=0)
    )
    y = np.full((2, 5), -np.inf, np.float32)
    y[1, 3] = 0.0
    np.testing.assert_array_equal(np.asarray(sampling.argmax_first(y)), [0, 3])


@pytest.mark.parametrize("k", [0, 1, 149, 2998, 2999])
def test_order_statistics_equal_a_sort(k):
    """The k-th and (k+1)-th smallest, bit for bit as a sort gives them, also with
    ties, zeros, negative values and one distinct value per row."""
    rng = np.random.default_rng(17 + k)
    x = rng.uniform(size=(6, 3000)).astype(np.float32)
    x[1, :400] = 0.25  # ties across the order statistics
    x[2] = np.round(x[2] * 8) / 8  # few distinct values
    x[3, :200] = 0.0
    x[4] -= 0.5  # negative values
    x[5] = 0.5  # one value
    lo, hi = jax.jit(sampling.order_statistics, static_argnums=1)(x, k)
    s = np.sort(x, axis=-1)
    np.testing.assert_array_equal(np.asarray(lo), s[:, k])
    np.testing.assert_array_equal(np.asarray(hi), s[:, min(k + 1, 2999)])


def test_order_statistics_refuses_out_of_range():
    with pytest.raises(ValueError, match="out of range"):
        sampling.order_statistics(jnp.zeros((2, 5)), 5)


def test_gamma_bins_ks_and_independent_of_other_bins():
    """Each bin's draws are exact Gamma draws, and a bin's draws do not change when
    the row holds other bins (more, fewer, in another order)."""
    shapes = np.array([[1.0, 3.0, 151.0, 1.0]], np.float32)
    g = np.asarray(
        jax.jit(sampling.gamma_bins, static_argnums=(2, 3))(
            _keys(21, 1), shapes, (0, 1, 2, sampling.MAX_BIN_ID), 20000
        )
    )[0]
    for v, a in enumerate(shapes[0]):
        assert scipy.stats.kstest(g[:, v], scipy.stats.gamma(a).cdf).pvalue > KS_LEVEL
    # bins 0 and 3 again, alone and in another order, beside a new bin 7
    other = np.asarray(
        sampling.gamma_bins(
            _keys(21, 1),
            np.array([[1.0, 5.0, 1.0]], np.float32),
            (sampling.MAX_BIN_ID, 7, 0),
            20000,
        )
    )[0]
    np.testing.assert_array_equal(other[:, 0], g[:, 3])
    np.testing.assert_array_equal(other[:, 2], g[:, 0])
    # distinct bins of equal shape are not the same draws
    assert not np.array_equal(g[:, 0], g[:, 3])


def test_gamma_bins_refuses_bad_ids():
    a = np.ones((1, 2), np.float32)
    with pytest.raises(ValueError, match="distinct"):
        sampling.gamma_bins(_keys(0, 1), a, (3, 3), 10)
    with pytest.raises(ValueError, match="distinct"):
        sampling.gamma_bins(_keys(0, 1), a, (0, sampling.MAX_BIN_ID + 1), 10)
