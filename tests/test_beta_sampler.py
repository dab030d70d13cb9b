"""Exactness tests of legs_jax.core.beta_sampler (Cheng's algorithm BA/BB/BC).

Every test uses fixed seeds, so it is deterministic. A statistical test's stated
level is the chance that an exact sampler would fail it with a fresh seed:
Kolmogorov-Smirnov and binomial tests at 1e-4 each (about 20 of them: a
family-wise level of about 0.2 %); moment tests at 6 standard errors.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from test_sampling import EXTREME_SHAPES

from legs_jax.core import beta_sampler, sampling

KS_LEVEL = 1e-4
DRAWS = 20_000

# Shapes 0.05 to 1e4: near the prior, posterior-like, large counts, very unequal
# pairs both ways round, and shapes below 1.
GRID = [
    (1.0, 1.0),
    (1.5, 1.5),
    (1.01, 1.99),
    (1.0, 3000.0),
    (2.0, 3000.0),
    (3000.0, 2.0),
    (30.0, 50.0),
    (151.3, 2501.7),
    (1500.0, 1500.0),
    (1e4, 1e4),
    (1e4, 1.0),
    (0.5, 0.5),
    (0.05, 0.05),
    (0.05, 2.0),
    (3.0, 0.5),
    (0.3, 700.0),
    (0.05, 1e4),
    (1e4, 0.05),
]

beta_rows_v2 = jax.jit(beta_sampler.beta_rows_v2)


def _keys(seed: int, n: int) -> jax.Array:
    return jax.random.split(jax.random.key(seed), n)


def _rows(shapes, n: int):
    a = np.repeat(np.array([s[0] for s in shapes], np.float32)[:, None], n, 1)
    b = np.repeat(np.array([s[1] for s in shapes], np.float32)[:, None], n, 1)
    return a, b


def _ks_pvalue(x: np.ndarray, dist, lo: float = 1e-30, hi: float = 1 - 1e-6) -> float:
    """KS p-value of float32 draws against ``dist`` conditioned on (lo, hi), and a
    two-sided binomial test of the mass outside (the smaller p-value).

    Float32 sends draws below ~1e-38 to 0 and cannot resolve those within 6e-8
    of 1, which a KS test on the raw draws would flag for shapes below 1.
    """
    x = np.asarray(x, np.float64).ravel()
    f_lo, f_hi = dist.cdf(lo), dist.cdf(hi)
    inside = x[(x > lo) & (x < hi)]

    def conditional(t):
        return (dist.cdf(t) - f_lo) / (f_hi - f_lo)

    p_ks = scipy.stats.kstest(inside, conditional).pvalue
    p_in = scipy.stats.binomtest(len(inside), len(x), f_hi - f_lo).pvalue
    return min(p_ks, p_in)


@pytest.fixture(scope="module")
def grid_draws() -> np.ndarray:
    a, b = _rows(GRID, DRAWS)
    return np.asarray(beta_rows_v2(_keys(1, len(GRID)), a, b))


@pytest.mark.parametrize("row", range(len(GRID)), ids=[str(s) for s in GRID])
def test_ks_against_scipy(grid_draws, row):
    alpha, beta = GRID[row]
    p = _ks_pvalue(grid_draws[row], scipy.stats.beta(alpha, beta))
    assert p > KS_LEVEL, (alpha, beta, p)


@pytest.mark.parametrize("row", range(len(GRID)), ids=[str(s) for s in GRID])
def test_mean_and_variance(grid_draws, row):
    """Sample mean and variance within 6 standard errors of Beta(a, b)'s."""
    alpha, beta = GRID[row]
    dist = scipy.stats.beta(alpha, beta)
    mean, var, _, kurt = (float(m) for m in dist.stats(moments="mvsk"))
    x = grid_draws[row].astype(np.float64)
    n = len(x)
    assert abs(x.mean() - mean) <= 6 * np.sqrt(var / n), (alpha, beta)
    # Standard error of the sample variance: var * sqrt((excess kurtosis + 2) / n).
    assert abs(x.var() - var) <= 6 * var * np.sqrt((kurt + 2) / n), (alpha, beta)


def test_values_in_unit_interval_and_rounding_rule(grid_draws):
    """Draws are finite and in [0, 1]; 0 and 1 appear only where float32 forces
    them, at the rate the exact distribution puts below ~1e-38 (0) or within
    2^-25 of 1 (rounds to 1)."""
    assert grid_draws.dtype == np.float32
    assert np.all(np.isfinite(grid_draws))
    assert np.all((grid_draws >= 0.0) & (grid_draws <= 1.0))
    for row, (alpha, beta) in enumerate(GRID):
        x = grid_draws[row]
        dist = scipy.stats.beta(alpha, beta)
        # P(exact draw within 2^-25 of 1) = P(1 - X < 2^-25), 1 - X ~ Beta(b, a).
        p_one = scipy.stats.beta(beta, alpha).cdf(2.0**-25)
        ones = int(np.sum(x == 1.0))
        if p_one < 1e-9:
            assert ones == 0, (alpha, beta)
        else:
            p = scipy.stats.binomtest(ones, len(x), p_one).pvalue
            assert p > KS_LEVEL, (alpha, beta, ones, p_one)
        # Zeros: below the normal range (flushed) at most, below the smallest
        # subnormal at least.
        zeros = int(np.sum(x == 0.0))
        p_lo, p_hi = dist.cdf(7e-46), dist.cdf(1.2e-38)
        if p_hi < 1e-9:
            assert zeros == 0, (alpha, beta)
        else:
            lo = scipy.stats.binom(len(x), p_lo).ppf(KS_LEVEL / 2)
            hi = scipy.stats.binom(len(x), p_hi).isf(KS_LEVEL / 2)
            assert lo <= zeros <= hi, (alpha, beta, zeros)
    # Most shapes: strictly inside (0, 1) (checked by the == 0 branches above);
    # (1e4, 1) does round to 1 now and then: P(1 - X < 2^-25) = 3e-4.
    assert np.all((grid_draws[0] > 0) & (grid_draws[0] < 1))


def _rejections(shape, n: int, tries: int) -> np.ndarray:
    """Which of the first ``tries`` tries of n elements of one row are rejected
    (counters as in beta_rows_v2, row key of _keys(3, 1))."""
    k0, k1 = sampling.key_words(_keys(3, 1))
    a = jnp.full((1, n), shape[0], jnp.float32)
    b = jnp.full((1, n), shape[1], jnp.float32)
    col = jnp.arange(n, dtype=jnp.uint32)[None]
    params = beta_sampler._params(a, b)
    out = []
    for t in range(tries):
        w0, w1 = sampling.threefry2x32(k0, k1, col, beta_sampler._counter(t))
        out.append(np.asarray(beta_sampler._try(params, w0, w1))[0] < 0)
    return np.stack(out)


def test_retry_paths_are_exercised():
    """A high-rejection shape sends most elements to the first retry buffer and
    many to the second (tries 2, 3, ...): the case the tests below draw."""
    rejected = _rejections((0.05, 1e4), 4000, 3)
    first = rejected[0]
    both = rejected[0] & rejected[1]
    assert first.mean() > 0.5
    assert both.sum() > 500  # elements that reach the second buffer
    assert (both & rejected[2]).sum() > 100  # and need try 3 or later


def test_tiny_retry_buffers_give_the_same_bits():
    """An element keeps the first accepted try of its own sequence: buffers of 2
    slots (hundreds of passes through both levels) change no bit."""
    k0, k1 = sampling.key_words(_keys(4, 3))
    a, b = _rows([(0.05, 1e4), (1.0, 3000.0), (1.5, 1.5)], 300)

    def draw(capacity, capacity2):
        fn = jax.jit(
            lambda k0, k1, a, b: beta_sampler._beta_rows(
                k0, k1, a, b, capacity=capacity, capacity2=capacity2
            )
        )
        return np.asarray(fn(k0, k1, jnp.asarray(a), jnp.asarray(b)))

    default = draw(None, None)
    np.testing.assert_array_equal(default, draw(2, 2))
    np.testing.assert_array_equal(default, draw(64, 2))
    np.testing.assert_array_equal(default, np.asarray(beta_rows_v2(_keys(4, 3), a, b)))


def test_distribution_through_small_retry_buffers():
    """With buffers far smaller than the pending count (many passes of each
    level), draws of high-rejection shapes still pass KS and the moment test."""
    shapes = [(0.05, 1e4), (1.0, 3000.0)]
    k0, k1 = sampling.key_words(_keys(5, 2))
    a, b = _rows(shapes, DRAWS)
    fn = jax.jit(
        lambda k0, k1, a, b: beta_sampler._beta_rows(
            k0, k1, a, b, capacity=1024, capacity2=128
        )
    )
    x = np.asarray(fn(k0, k1, jnp.asarray(a), jnp.asarray(b)))
    for row, (alpha, beta) in enumerate(shapes):
        dist = scipy.stats.beta(alpha, beta)
        assert _ks_pvalue(x[row], dist) > KS_LEVEL, (alpha, beta)
        mean, var = (float(m) for m in dist.stats())
        assert abs(x[row].mean() - mean) <= 6 * np.sqrt(var / DRAWS), (alpha, beta)


def test_deterministic_and_batch_invariant():
    """Row i depends only on keys[i], a[i], b[i] (a batch of 6, two batches of 3
    and single rows give the same bits), element j only on j and its shapes (a
    prefix of a row is the narrower draw), and the same keys give the same bits
    again."""
    rng = np.random.default_rng(6)
    keys = _keys(7, 6)
    a = (1.0 + rng.gamma(1.0, 20.0, (6, 1000))).astype(np.float32)
    b = (1.0 + rng.gamma(1.0, 20.0, (6, 1000))).astype(np.float32)
    a[4, :10] = 0.3  # shapes below 1 mixed in
    b[5, ::3] = 0.05
    whole = np.asarray(beta_rows_v2(keys, a, b))
    np.testing.assert_array_equal(whole, np.asarray(beta_rows_v2(keys, a, b)))
    halves = [
        np.asarray(beta_rows_v2(keys[i : i + 3], a[i : i + 3], b[i : i + 3]))
        for i in (0, 3)
    ]
    np.testing.assert_array_equal(whole, np.concatenate(halves))
    for i in range(6):
        single = beta_rows_v2(keys[i : i + 1], a[i : i + 1], b[i : i + 1])
        np.testing.assert_array_equal(whole[i : i + 1], np.asarray(single))
    prefix = beta_rows_v2(keys, a[:, :256], b[:, :256])
    np.testing.assert_array_equal(whole[:, :256], np.asarray(prefix))
    # Other keys, other draws (rows 0-3: row 5's Beta(a, 0.05) often rounds to
    # 1); raw uint32 keys are the typed ones' data.
    other = np.asarray(beta_rows_v2(_keys(8, 6), a, b))
    assert np.mean(other[:4] == whole[:4]) < 0.001
    raw = np.asarray(beta_rows_v2(jax.random.key_data(keys), a, b))
    np.testing.assert_array_equal(whole, raw)


def test_shapes_dtypes_and_broadcasting():
    keys = _keys(9, 2)
    a = np.full((2, 5), 2.0, np.float32)
    x = beta_rows_v2(keys, a, 3.0)
    assert x.shape == (2, 5) and x.dtype == jnp.float32
    np.testing.assert_array_equal(
        np.asarray(x), np.asarray(beta_rows_v2(keys, a, np.full((2, 5), 3.0)))
    )
    assert beta_rows_v2(keys[:1], np.ones((1, 1)), np.ones((1, 1))).shape == (1, 1)
    assert beta_rows_v2(keys, np.ones((2, 0)), np.ones((2, 0))).shape == (2, 0)
    with pytest.raises(ValueError):
        beta_sampler.beta_rows_v2(jnp.zeros((2, 3), jnp.uint32), a, a)


EXTREME = EXTREME_SHAPES  # the old sampler's test's shapes


def test_extreme_shapes_finite_and_centred():
    """Shapes far outside the methods' range still give finite draws in [0, 1]
    with the right mean (shape 0 is treated as 1e-30: a point mass at 0)."""
    a, b = _rows(EXTREME, 2000)
    x = np.asarray(beta_rows_v2(_keys(10, len(EXTREME)), a, b))
    assert np.all(np.isfinite(x)) and np.all((x >= 0) & (x <= 1))
    for row, (alpha, beta) in enumerate(EXTREME):
        mean = alpha / (alpha + beta) if alpha > 0 else 0.0
        sd = np.sqrt(mean * (1 - mean) / (alpha + beta + 1))
        assert abs(x[row].mean() - mean) < 6 * sd / np.sqrt(2000) + 1e-6, (alpha, beta)


def test_version_constants():
    assert beta_sampler.SAMPLER_VERSION != beta_sampler.PREVIOUS_SAMPLER_VERSION
    assert beta_sampler.SAMPLER_VERSION and beta_sampler.PREVIOUS_SAMPLER_VERSION


def test_the_thompson_methods_draw_with_this_sampler():
    """thompson_draw (and with it the slot methods' select) takes the first
    argmax of this sampler's draws over the mask, not of the old sampler's."""
    from legs_jax.core.methods import base

    rng = np.random.default_rng(5)
    B, N = 64, 300
    a = jnp.asarray(1.0 + rng.integers(0, 6, (B, N)) + rng.uniform(0, 1, (B, N)))
    b = jnp.asarray(1.0 + rng.integers(0, 6, (B, N)) + rng.uniform(0, 1, (B, N)))
    mask = jnp.asarray(rng.uniform(size=(B, N)) < 0.7)
    keys = jax.random.split(jax.random.key(11), B)
    got = np.asarray(jax.jit(base.thompson_draw)(keys, a, b, mask))
    aa, bb = jnp.where(mask, a, 1.0), jnp.where(mask, b, 1.0)
    for sampler, same in (
        (beta_sampler.beta_rows_v2, True),
        (sampling.beta_rows, False),
    ):
        phi = np.asarray(jax.jit(sampler)(keys, aa, bb))
        want = np.argmax(np.where(np.asarray(mask), phi, -1.0), axis=1)
        if same:
            np.testing.assert_array_equal(got, want)
        else:  # independent streams: the argmax of 300 draws differs almost always
            assert (got != want).mean() > 0.5
