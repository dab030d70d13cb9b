"""Exact random variates and quantiles used by the engine, fast on CPU and GPU.

Every sampler takes one key per row (``keys: [B]``) and a row's values depend only on
its own key and parameters, so results never depend on batch size, batch order or
device count. Within a row, element ``j`` of a draw depends only on the key, ``j``
and that element's parameters (not on the row's width).

How the samplers are built (all plain ``jnp`` ops, so XLA fuses them):

- Random words: Threefry-2x32 (20 rounds, the generator behind ``jax.random``),
  written out with ``jnp`` integer ops and evaluated on a counter
  ``(element index, stream | try)`` under the row's key. It is bit-identical to
  ``jax.extend.random.threefry_2x32``.
- Gamma(a), a >= 1: Marsaglia & Tsang (2000). The acceptance test is written with
  ``log1p`` so that it does not lose precision for large shapes. Every element gets
  one try in bulk; the few rejected ones (0.3-3 %) are packed into a small buffer
  (the pending mask is packed into 32-bit words, prefix sums by small matrix
  products) and retried there, a few tries at a time, inside a ``lax.while_loop``
  until none is left. The tries of an element come from its own counter sequence
  and an element keeps its first accepted try, so the result is an exact Gamma
  draw, independent of every other element and of the rest of the batch.
- Gamma(a), 0 < a < 1: the boost G(a) = G(a + 1) * U^(1/a), in log space.
- Beta(a, b) = G_a / (G_a + G_b), in one fused pass: try 0 of the two gammas takes
  its two normals from one Box-Muller pair; elements with a rejected gamma (1-6 %)
  are packed into a buffer and finished there (tries t >= 1 with a normal from
  ``erf_inv``, one try per loop iteration until every gamma is accepted).
- On CPU most of the cost of the retries was not the tries but how XLA compiled
  them: the packed indices were recomputed inside every gather that used them
  (:func:`_materialized` computes them once), and the bulk pass splits into many
  passes when its result has more than one consumer (it feeds one loop only).
- Beta quantiles: safeguarded Newton-Halley on a float32 regularised incomplete beta
  function whose log prefactor is computed from Stirling's series (accurate for
  shapes in the thousands, where ``lgamma`` in float32 is not).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

__all__ = [
    "argmax_first",
    "beta_ppf",
    "beta_rows",
    "betainc",
    "gamma_bins",
    "gamma_rows",
    "key_words",
    "order_statistics",
    "threefry2x32",
    "uniform_bits",
    "uniform_rows",
]

# Counter streams: the high byte of the second counter word. A try number or a
# word index fills the low 24 bits.
_STREAM_GAMMA_A = 0
_STREAM_GAMMA_B = 1
_STREAM_BOOST = 2
_STREAM_UNIFORM = 3
_STREAM_PAIR = 4  # Box-Muller words of try 0 of a Beta draw's two gammas
_STREAM_ACCEPT = 5  # acceptance words of that try 0
_STREAM_BINS = 7  # gammas of Dirichlet bins (see gamma_bins)
_STREAM_SHIFT = 24

# Shapes below this are treated as this (Beta(a, b) with a -> 0 tends to a point
# mass at 0; the clamp keeps draws and quantiles finite).
_MIN_SHAPE = 1e-30


# --------------------------------------------------------------------------------------
# Random words
# --------------------------------------------------------------------------------------


def _rotl(x, r: int, xp=jnp):
    return (x << xp.uint32(r)) | (x >> xp.uint32(32 - r))


def threefry2x32(k0, k1, x0, x1, xp=jnp):
    """Threefry-2x32 (20 rounds) of the counter (x0, x1) under the key (k0, k1).

    All arguments are uint32 arrays that broadcast together; returns two uint32
    arrays of the broadcast shape. Bit-identical to the generator of ``jax.random``.
    ``xp=numpy`` computes the same words on the host, with no JAX program (NumPy
    arrays wrap around as uint32 arithmetic does).
    """
    k0 = xp.asarray(k0, xp.uint32)
    k1 = xp.asarray(k1, xp.uint32)
    k2 = k0 ^ k1 ^ xp.uint32(0x1BD11BDA)
    ks = (k0, k1, k2)
    rotations = ((13, 15, 26, 6), (17, 29, 16, 24))
    x0 = xp.asarray(x0, xp.uint32) + k0
    x1 = xp.asarray(x1, xp.uint32) + k1
    for i in range(5):
        for r in rotations[i % 2]:
            x0 = x0 + x1
            x1 = _rotl(x1, r, xp)
            x1 = x1 ^ x0
        x0 = x0 + ks[(i + 1) % 3]
        x1 = x1 + ks[(i + 2) % 3] + xp.uint32(i + 1)
    return x0, x1


def key_words(keys: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The two uint32 key words of each of ``keys`` [B], as two [B, 1] arrays.

    Accepts typed Threefry keys (``jax.random.key``) or raw uint32 keys [B, 2].
    """
    if jnp.issubdtype(keys.dtype, jax.dtypes.prng_key):
        data = jax.random.key_data(keys)
    else:
        data = jnp.asarray(keys)
    if data.ndim != 2 or data.shape[-1] != 2 or data.dtype != jnp.uint32:
        raise ValueError(
            "expected one Threefry key per row (typed keys of shape [B] or uint32 "
            f"[B, 2]); got key data of shape {data.shape} and dtype {data.dtype}"
        )
    return data[:, 0:1], data[:, 1:2]


def _counter_words(k0: jax.Array, k1: jax.Array, n: int, stream: int) -> jax.Array:
    """[B, n] random words: word j is half of Threefry((j // 2, stream << 24))."""
    half = (n + 1) // 2
    j = jnp.arange(half, dtype=jnp.uint32)[None]
    w0, w1 = threefry2x32(k0, k1, j, jnp.uint32(stream << _STREAM_SHIFT))
    return jnp.stack([w0, w1], axis=-1).reshape(k0.shape[0], 2 * half)[:, :n]


def uniform_bits(keys: jax.Array, n: int) -> jax.Array:
    """[B, n] uint32 random words, one row per key (keys consumed).

    Word j of a row does not depend on n (a prefix of a longer draw is the shorter
    draw).
    """
    k0, k1 = key_words(keys)
    return _counter_words(k0, k1, n, _STREAM_UNIFORM)


def _open_unit(bits: jax.Array) -> jax.Array:
    """Uniform on the open interval (0, 1) from the top 24 bits of a word."""
    return ((bits >> jnp.uint32(8)).astype(jnp.float32) + 0.5) * jnp.float32(2.0**-24)


def uniform_rows(keys: jax.Array, n: int) -> jax.Array:
    """[B, n] float32 uniforms on the open interval (0, 1) (24 random bits each)."""
    return _open_unit(uniform_bits(keys, n))


# --------------------------------------------------------------------------------------
# Gamma and Beta
# --------------------------------------------------------------------------------------


def _mt_try(d, c, w0, w1, rejected):
    """One Marsaglia-Tsang try for Gamma(d + 1/3) from the words (w0, w1).

    Returns the draw where the try is accepted, else ``rejected`` (negative). One
    output array, so that XLA computes the try in a single fusion.
    """
    # Standard normal from erf_inv of a uniform on (-1, 1).
    s = ((w0 >> jnp.uint32(8)).astype(jnp.float32) + 0.5) * jnp.float32(2.0**-23) - 1.0
    x = jnp.float32(math.sqrt(2.0)) * jax.lax.erf_inv(s)
    return _mt_accept(d, c, x, _open_unit(w1), rejected)


def _select_bit(word: jax.Array, rank: jax.Array) -> jax.Array:
    """Position of the set bit of rank ``rank`` (0-based, from bit 0) in ``word``."""
    pos = jnp.zeros(word.shape, jnp.int32)
    for width in (16, 8, 4, 2, 1):
        low = word & jnp.uint32((1 << width) - 1)
        count = jax.lax.population_count(low).astype(jnp.int32)
        high = rank >= count
        rank = jnp.where(high, rank - count, rank)
        word = jnp.where(high, word >> jnp.uint32(width), low)
        pos = pos + jnp.where(high, width, 0)
    return pos


def _exclusive_prefix_sum(counts: jax.Array) -> jax.Array:
    """Exclusive prefix sum of small non-negative int32 counts (1-D).

    Two small matrix products with triangular matrices of ones (exact in float32
    for totals below 2**24): on CPU much faster than XLA's cumulative sum, which
    becomes a tree of reduce-windows.
    """
    (n,) = counts.shape
    w = 64
    r = -(-n // w)
    c = jnp.pad(counts, (0, r * w - n)).astype(jnp.float32).reshape(r, w)
    exact = jax.lax.Precision.HIGHEST  # no reduced-precision products (GPUs)
    within = jnp.matmul(c, jnp.triu(jnp.ones((w, w), jnp.float32), 1), precision=exact)
    tri = jnp.triu(jnp.ones((r, r), jnp.float32), 1)
    blocks = jnp.matmul(jnp.sum(c, axis=1), tri, precision=exact)
    return (within + blocks[:, None]).reshape(-1)[:n].astype(jnp.int32)


def _materialized(x: jax.Array, bound) -> jax.Array:
    """``x`` (int32, values in [0, bound]) computed once into a buffer of its own.

    XLA would otherwise fuse the computation of ``x`` into each of its consumers
    (here several gathers) and run it once per consumer. A while loop of one
    iteration (its trip count unknown to the compiler) returns it unchanged.
    """

    def body(state):
        i, x = state
        return i + 1, jnp.where(x > bound + i, 0, x)

    _, x = jax.lax.while_loop(lambda s: s[0] < 1, body, (jnp.min(x) // (bound + 1), x))
    return x


def _pending_slots(pending: jax.Array, capacity: int, *, with_count: bool = False):
    """Indices of the first ``capacity`` True entries of ``pending``.

    [M] bool -> [capacity] int32, padded with ``M`` (and, ``with_count``, the
    number of True entries, which may exceed ``capacity``). The mask is packed
    into 32-bit words; prefix sums run over the M / 32 word counts. The word of
    slot s is the number of words whose pending entries all come before s, counted
    with a histogram of the words' ends and a prefix sum over the slots; the rank
    within the word gives the bit.
    """
    (m,) = pending.shape
    nw = -(-m // 32)
    padded = jnp.pad(pending, (0, nw * 32 - m))
    bits = padded.reshape(nw, 32).astype(jnp.uint32) << jnp.arange(32, dtype=jnp.uint32)
    words = jnp.sum(bits, axis=1, dtype=jnp.uint32)  # [nw]
    counts = jax.lax.population_count(words).astype(jnp.int32)
    before = _exclusive_prefix_sum(counts)
    ends = jnp.zeros((capacity + 1,), jnp.int32).at[before + counts].add(1, mode="drop")
    block = _exclusive_prefix_sum(ends)[1:]  # words ending at or before each slot
    slot = jnp.arange(capacity, dtype=jnp.int32)
    valid = slot < before[-1] + counts[-1]
    block = jnp.minimum(block, nw - 1)  # (only past the last pending entry)
    pos = block * 32 + _select_bit(words[block], slot - before[block])
    idx = jnp.where(valid, pos, m)
    idx = _materialized(idx, m)
    return (idx, before[-1] + counts[-1]) if with_count else idx


def _finish_pending(x: jax.Array, capacity: int, finish) -> jax.Array:
    """Fill the negative (pending) entries of ``x`` [M], ``capacity`` at a time.

    ``finish(x, idx)`` returns ``x`` with the entries ``idx`` ([capacity], M where
    unused) done. Passes repeat until none is pending; the first always runs (its
    loop state keeps the bulk pass that made ``x`` a single fusion: XLA splits it
    when its result has more than one consumer).
    """

    def one_pass(state):
        x, _ = state
        idx, count = _pending_slots(x < 0.0, capacity, with_count=True)
        return finish(x, idx), count - capacity

    x, _ = jax.lax.while_loop(lambda s: s[1] > 0, one_pass, (x, jnp.int32(1)))
    return x


def _plain_counters(stream: int):
    """Counters of element j: (j, stream << 24) (try t adds t to the second)."""

    def counters(col):
        col = col.astype(jnp.uint32)
        return col, jnp.full(col.shape, stream << _STREAM_SHIFT, jnp.uint32)

    return counters


def _gamma_ge1(k0, k1, a, counters, capacity=None):
    """Gamma(a') draws ([B, M] float32) for a' = a + 1 where a < 1, else a.

    (Callers boost the draws of shapes below 1 afterwards.)

    ``counters(j)`` maps element indices j (int32 array) to the two uint32 counter
    words of their first try; try t adds t to the second word. Every element takes
    the first accepted try of its own sequence 0, 1, 2, ..., whatever the batch
    holds, so the values do not depend on which rejected elements share a retry
    pass. The first try of every element runs in bulk; the rejected ones
    (0.3-5 %) are packed into a buffer of ``capacity`` slots and finished there,
    one try per loop iteration until every element of the buffer is accepted;
    passes repeat until none is left.
    """
    rows, m = a.shape

    def shape_d(a):
        return jnp.where(a < 1.0, a + 1.0, a) - jnp.float32(1.0 / 3.0)

    d = shape_d(a)
    c = jax.lax.rsqrt(9.0 * d)
    c0, c1 = counters(jnp.arange(m, dtype=jnp.int32))
    w0, w1 = threefry2x32(k0, k1, c0[None], c1[None])
    g = _mt_try(d, c, w0, w1, jnp.float32(-1.0)).reshape(-1)
    total = rows * m
    if capacity is None:
        # A multiple of 64: XLA's CPU loops run scalar over odd lengths.
        capacity = -(-(total // 64 + 64) // 64) * 64
    # At least 2 slots: XLA compiles one-element arrays differently, and the last
    # bit of a value must not depend on the buffer it went through.
    capacity = max(2, capacity)
    a_flat = a.reshape(-1)
    key_pairs = jnp.concatenate([k0, k1], axis=1)  # [B, 2]

    def finish(g, idx):
        """Finish the elements ``idx`` (``total`` where unused), tries t >= 1."""
        idx_c = jnp.minimum(idx, total - 1)
        row = idx_c // m
        ds = shape_d(a_flat[idx_c])
        cs = jax.lax.rsqrt(9.0 * ds)
        kp = key_pairs[row]  # one gather for both words
        r0, r1 = kp[:, 0], kp[:, 1]
        b0, b1 = counters(idx_c - row * m)

        # (A loop, not unrolled: its state is a plain [C] array, so that XLA
        # emits vector code for the tries.)
        def one_try(state):
            t, gs = state
            v0, v1 = threefry2x32(r0, r1, b0, b1 + t.astype(jnp.uint32))
            gt = _mt_try(ds, cs, v0, v1, jnp.float32(-1.0))
            return t + 1, jnp.where(gs < 0.0, gt, gs)

        init = (jnp.int32(1), jnp.full(idx.shape, -1.0, jnp.float32))
        _, gs = jax.lax.while_loop(lambda s: jnp.any(s[1] < 0.0), one_try, init)
        return g.at[idx].set(gs, mode="drop")

    return _finish_pending(g, capacity, finish).reshape(rows, m)


def _boosted_log(g, a, boost_bits):
    """log Gamma(a) from g ~ Gamma(a + 1) by the boost G(a) = G(a + 1) U^(1/a).

    In log space, so that it cannot underflow; ``boost_bits`` are the words for U.
    """
    a = jnp.maximum(a, _MIN_SHAPE)
    return jnp.log(g) + jnp.log(_open_unit(boost_bits)) / a


def gamma_rows(keys: jax.Array, a: jax.Array) -> jax.Array:
    """Exact Gamma(a, 1) draws, one key per row.

    Args:
      keys: [B] typed PRNG keys (consumed).
      a: [B, M] shapes, > 0.
    Returns:
      [B, M] float32 draws (draws of shapes below 1 may underflow to 0).
    """
    k0, k1 = key_words(keys)
    a = jnp.asarray(a, jnp.float32)
    m = a.shape[1]
    small = a < 1.0
    g = _gamma_ge1(k0, k1, a, _plain_counters(_STREAM_GAMMA_A))

    def boost(g):
        bits = _counter_words(k0, k1, 2 * m, _STREAM_BOOST)[:, 0::2]
        return jnp.where(small, jnp.exp(_boosted_log(g, a, bits)), g)

    return jax.lax.cond(jnp.any(small), boost, lambda g: g, g)


# gamma_bins: the second counter word is stream << 24 | bin id << 12 | try.
_BIN_SHIFT = 12
MAX_BIN_ID = (1 << (_STREAM_SHIFT - _BIN_SHIFT)) - 1  # 4095


def gamma_bins(keys: jax.Array, a: jax.Array, bin_ids, num_samples: int) -> jax.Array:
    """``num_samples`` exact Gamma(a_v) draws for each bin v of each row.

    Sample m of bin v draws from the counters (m, stream | id_v << 12 | try) under
    the row's key, so a bin's draws depend only on the key, m, the bin's id and
    its shape: not on which other bins the row holds, nor on how many (a
    Dirichlet over an object's poses gives the same draws whatever padding its
    batch adds). Marsaglia-Tsang, one try in bulk, the rejected ones retried in a
    packed buffer (as :func:`gamma_rows`); an element keeps its first accepted try
    (fewer than 4096 tries: a rejection rate below 5 % makes more impossible in
    practice).

    Args:
      keys: [B] keys (consumed).
      a: [B, V] shapes, >= 1.
      bin_ids: V distinct integers in [0, :data:`MAX_BIN_ID`] (static).
      num_samples: M.
    Returns:
      [B, M, V] float32 draws.
    """
    ids = [int(i) for i in bin_ids]
    rows, v = a.shape
    if (
        len(ids) != v
        or len(set(ids)) != v
        or not all(0 <= i <= MAX_BIN_ID for i in ids)
    ):
        raise ValueError(
            f"bin_ids must be {v} distinct integers in [0, {MAX_BIN_ID}], got {ids}"
        )
    k0, k1 = key_words(keys)
    shapes = jnp.broadcast_to(
        jnp.asarray(a, jnp.float32)[:, None, :], (rows, num_samples, v)
    ).reshape(rows, num_samples * v)
    id_words = jnp.asarray(
        [(_STREAM_BINS << _STREAM_SHIFT) | (i << _BIN_SHIFT) for i in ids], jnp.uint32
    )

    def counters(j):
        m = j // v
        return m.astype(jnp.uint32), id_words[j - m * v]

    g = _gamma_ge1(k0, k1, shapes, counters)
    return g.reshape(rows, num_samples, v)


def _sincos_2pi(t: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(sin 2 pi t, cos 2 pi t) for t in [0, 1): Taylor polynomials on a quadrant
    (error below 1e-7), cheaper than the general ``sin``/``cos``."""
    x4 = t * 4.0
    q = jnp.floor(x4)
    f = (x4 - q) * jnp.float32(math.pi / 2)  # [0, pi / 2)
    f2 = f * f
    s = f * (
        1.0
        + f2
        * (
            -1 / 6
            + f2 * (1 / 120 + f2 * (-1 / 5040 + f2 * (1 / 362880 - f2 / 39916800)))
        )
    )
    c = 1.0 + f2 * (
        -0.5
        + f2
        * (
            1 / 24
            + f2 * (-1 / 720 + f2 * (1 / 40320 + f2 * (-1 / 3628800 + f2 / 479001600)))
        )
    )
    qi = q.astype(jnp.int32)
    sin = jnp.where(qi == 0, s, jnp.where(qi == 1, c, jnp.where(qi == 2, -s, -c)))
    cos = jnp.where(qi == 0, c, jnp.where(qi == 1, -s, jnp.where(qi == 2, -c, s)))
    return sin, cos


def _mt_accept(d, c, x, u, rejected):
    """Marsaglia-Tsang for Gamma(d + 1/3) from a normal x and a uniform u."""
    w = c * x
    ok_v = w > -1.0
    lw = jnp.log1p(jnp.where(ok_v, w, 0.0))
    # log acceptance threshold 0.5 x^2 + d - d v + d log v with v = (1 + w)^3,
    # written so that the O(d) terms cancel analytically.
    thr = 0.5 * x * x + d * (3.0 * (lw - w) - w * w * (3.0 + w))
    ok = ok_v & (jnp.log(u) < thr)
    v = (1.0 + w) * (1.0 + w) * (1.0 + w)
    return jnp.where(ok, d * v, rejected)


def _shape_dc(a):
    """(d, c) of Marsaglia-Tsang for the shape a' = a + 1 (a < 1) or a."""
    d = jnp.where(a < 1.0, a + 1.0, a) - jnp.float32(1.0 / 3.0)
    return d, jax.lax.rsqrt(9.0 * d)


def _beta_first_tries(k0, k1, i, da, ca, db, cb):
    """Try 0 of both gammas of Beta element i (negative where rejected).

    The two normals are the Box-Muller pair of one pair of words, the two
    acceptance uniforms the pair of words of a second counter.
    """
    p0, p1 = threefry2x32(k0, k1, i, jnp.uint32(_STREAM_PAIR << _STREAM_SHIFT))
    q0, q1 = threefry2x32(k0, k1, i, jnp.uint32(_STREAM_ACCEPT << _STREAM_SHIFT))
    r = jnp.sqrt(-2.0 * jnp.log(_open_unit(p0)))
    sin, cos = _sincos_2pi(_open_unit(p1))
    ga = _mt_accept(da, ca, r * cos, _open_unit(q0), jnp.float32(-1.0))
    gb = _mt_accept(db, cb, r * sin, _open_unit(q1), jnp.float32(-1.0))
    return ga, gb


def _beta_value(k0, k1, i, a, b, ga, gb, boost: bool):
    """Ga / (Ga + Gb) where both gammas are accepted, else -1; with ``boost``, the
    draws of shapes below 1 get the boost G(a) = G(a + 1) U^(1/a) (log space)."""
    x = ga / (ga + gb)
    if boost:
        small = (a < 1.0) | (b < 1.0)
        ua, ub = threefry2x32(k0, k1, i, jnp.uint32(_STREAM_BOOST << _STREAM_SHIFT))
        la = jnp.log(ga) + jnp.where(
            a < 1.0, jnp.log(_open_unit(ua)) / jnp.maximum(a, _MIN_SHAPE), 0.0
        )
        lb = jnp.log(gb) + jnp.where(
            b < 1.0, jnp.log(_open_unit(ub)) / jnp.maximum(b, _MIN_SHAPE), 0.0
        )
        # Ga / (Ga + Gb) = sigmoid(log Ga - log Gb), finite for any shapes.
        x = jnp.where(small, jax.nn.sigmoid(la - lb), x)
    return jnp.where((ga >= 0.0) & (gb >= 0.0), x, jnp.float32(-1.0))


def beta_rows(keys: jax.Array, a: jax.Array, b: jax.Array) -> jax.Array:
    """Exact Beta(a, b) draws, one key per row: Ga / (Ga + Gb).

    Element i of a row draws from counters (i, stream | try) under the row's key.
    Try 0 of the two gammas runs in bulk, with the two normals of one Box-Muller
    pair (cheaper than two inverse error functions) and the whole draw in one
    fused pass. The few elements where a gamma was rejected (1-5 %) are packed
    into a buffer and redrawn there from scratch, try after try (try t >= 1: its
    own pair of words, normal from ``erf_inv``), until both gammas have an
    accepted try; an element always ends with the first accepted try of each
    gamma, whatever the batch holds. Shapes below 1 use the boost (an extra
    uniform per gamma), in log space.

    Args:
      keys: [B] typed PRNG keys (consumed).
      a, b: [B, N] shape parameters, > 0 (float32). Shapes below 1 are exact too.
    Returns:
      [B, N] float32 draws in [0, 1].
    """
    k0, k1 = key_words(keys)
    a = jnp.asarray(a, jnp.float32)
    b = jnp.asarray(b, jnp.float32)
    a, b = jnp.broadcast_arrays(a, b)
    any_small = jnp.any((a < 1.0) | (b < 1.0))
    return jax.lax.cond(
        any_small,
        lambda: _beta_rows(k0, k1, a, b, boost=True),
        lambda: _beta_rows(k0, k1, a, b, boost=False),
    )


def _gamma_pair_try(r0, r1, col, t, dsa, csa, dsb, csb, ga, gb):
    """Try t >= 1 of both gammas of Beta elements (counters ``col``), kept only
    where that gamma is still pending (negative)."""
    tt = jnp.asarray(t, jnp.uint32)
    wa0, wa1 = threefry2x32(
        r0, r1, col, jnp.uint32(_STREAM_GAMMA_A << _STREAM_SHIFT) + tt
    )
    wb0, wb1 = threefry2x32(
        r0, r1, col, jnp.uint32(_STREAM_GAMMA_B << _STREAM_SHIFT) + tt
    )
    ga = jnp.where(ga < 0.0, _mt_try(dsa, csa, wa0, wa1, jnp.float32(-1.0)), ga)
    gb = jnp.where(gb < 0.0, _mt_try(dsb, csb, wb0, wb1, jnp.float32(-1.0)), gb)
    return ga, gb


def _beta_rows(k0, k1, a, b, *, boost: bool, capacity=None):
    rows, n = a.shape
    total = rows * n
    da, ca = _shape_dc(a)
    db, cb = _shape_dc(b)
    i = jnp.arange(n, dtype=jnp.uint32)[None]
    ga, gb = _beta_first_tries(k0, k1, i, da, ca, db, cb)
    x = _beta_value(k0, k1, i, a, b, ga, gb, boost).reshape(-1)
    if capacity is None:
        # A multiple of 64: XLA's CPU loops run scalar over odd lengths.
        capacity = -(-(total // 16 + 32) // 64) * 64
    capacity = max(2, capacity)
    a_flat, b_flat = a.reshape(-1), b.reshape(-1)
    key_pairs = jnp.concatenate([k0, k1], axis=1)  # [B, 2]

    def redraw(x, idx):
        """Finish the elements ``idx`` (``total`` where unused) from scratch."""
        idx_c = jnp.minimum(idx, total - 1)
        row = idx_c // n
        col = (idx_c - row * n).astype(jnp.uint32)
        kp = key_pairs[row]  # one gather for both words
        r0, r1 = kp[:, 0], kp[:, 1]
        sa, sb = a_flat[idx_c], b_flat[idx_c]
        dsa, csa = _shape_dc(sa)
        dsb, csb = _shape_dc(sb)
        ga, gb = _beta_first_tries(r0, r1, col, dsa, csa, dsb, csb)

        # Try t of the gammas still rejected, until every gamma of the buffer has
        # its first accepted try. (A loop, not unrolled: its state is a plain
        # [C] array, so that XLA emits vector code for the tries.)
        def pending(state):
            return jnp.any((state[1] < 0.0) | (state[2] < 0.0))

        def one_try(state):
            t, ga, gb = state
            ga, gb = _gamma_pair_try(r0, r1, col, t, dsa, csa, dsb, csb, ga, gb)
            return t + 1, ga, gb

        _, ga, gb = jax.lax.while_loop(pending, one_try, (jnp.int32(1), ga, gb))
        xs = _beta_value(r0, r1, col, sa, sb, ga, gb, boost)
        return x.at[idx].set(xs, mode="drop")

    return _finish_pending(x, capacity, redraw).reshape(rows, n)


# --------------------------------------------------------------------------------------
# Incomplete beta and its inverse
# --------------------------------------------------------------------------------------

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def _stirling_series(z: jax.Array) -> jax.Array:
    """lgamma(z) - [(z - 1/2) log z - z + log(2 pi)/2] for z >= 6 (error < 1e-9)."""
    r2 = 1.0 / (z * z)
    return (1.0 / z) * (
        1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0 - r2 / 1680.0))
    )


def _stirling_rest(z: jax.Array) -> jax.Array:
    """lgamma(z) - [(z - 1/2) log z - z + log(2 pi)/2], accurate for all z > 0.

    Below 10, by the recurrence lgamma(z) = lgamma(z + 6) - log(z (z + 1) ... (z + 5))
    and the series at z + 6 (cheaper than ``lgamma``; about 1e-6 absolute).
    """
    big = z >= 10.0
    zb = jnp.where(big, z, 10.0)
    zs = jnp.where(big, 1.0, z)
    z6 = zs + 6.0
    prod = zs * (zs + 1.0) * (zs + 2.0) * (zs + 3.0) * (zs + 4.0) * (zs + 5.0)
    small = (
        (z6 - 0.5) * jnp.log(z6)
        - 6.0
        + _stirling_series(z6)
        - jnp.log(prod)
        - (zs - 0.5) * jnp.log(zs)
    )
    return jnp.where(big, _stirling_series(zb), small)


def _log1pmx(e: jax.Array) -> jax.Array:
    """log(1 + e) - e, accurate also for small |e| (e > -1)."""
    small = jnp.abs(e) < 0.5
    es = jnp.where(small, e, 0.0)
    u = es / (2.0 + es)
    u2 = u * u
    series = u2 * (1.0 / 11.0 + u2 / 13.0)
    for k in (9.0, 7.0, 5.0, 3.0):
        series = u2 * (1.0 / k + series)
    near = -es * es / (2.0 + es) + 2.0 * u * series
    el = jnp.where(small, 0.0, e)
    return jnp.where(small, near, jnp.log1p(el) - el)


def _log_prefactor_at_peak(a, b):
    """f(x0) - log B(a, b) for f(x) = a log x + b log(1 - x), x0 = a / (a + b)."""
    c = a + b
    return (
        0.5 * (jnp.log(a) + jnp.log(b) - jnp.log(c))
        - _HALF_LOG_2PI
        - _stirling_rest(a)
        - _stirling_rest(b)
        + _stirling_rest(c)
    )


def _log_prefactor(a, b, x, at_peak=None):
    """log[x^a (1 - x)^b / B(a, b)], accurate for shapes in the thousands.

    Split as [f(x) - f(x0)] + [f(x0) - log B(a, b)] with f(x) = a log x +
    b log(1 - x) and x0 = a / (a + b) its maximiser: the first part is written with
    log1p(e) - e so that its O(a + b) terms cancel analytically, the second with
    Stirling's series. (``lgamma`` in float32 loses ~1e-3 at shapes ~ 3000.)
    """
    c = a + b
    x0 = a / c
    y0 = 1.0 - x0
    dx = x - x0
    peak_gap = a * _log1pmx(dx / x0) + b * _log1pmx(-dx / y0) + dx * (a / x0 - b / y0)
    if at_peak is None:
        at_peak = _log_prefactor_at_peak(a, b)
    return peak_gap + at_peak


_CF_MAX_ITER = 300
_CF_UNROLL = 4
# Relative change of the fraction below which it counts as converged: above the
# few-ulp rounding noise of the recurrence.
_CF_TOL = 1e-6


def _cf_terms(a, b, x, m):
    """The two partial numerators (num, den) of iteration m of the fraction."""
    m2 = 2.0 * m
    even = (m * (b - m) * x, (a - 1.0 + m2) * (a + m2))
    odd = (-(a + m) * (a + b + m) * x, (a + m2) * (a + 1.0 + m2))
    return even, odd


def _cf_start(a, b, x):
    """Wallis state (A_prev, A_cur, B_prev, B_cur) after the first numerator."""
    one = jnp.ones_like(x)
    return one, one, one, 1.0 - (a + b) * x / (a + 1.0)


def _cf_iterate(a, b, x, m, state):
    """One iteration (two partial numerators) of the forward recurrence, rescaled."""
    a_prev, a_cur, b_prev, b_cur = state
    for num, den in _cf_terms(a, b, x, m):
        a_prev, a_cur = den * a_cur, den * a_cur + num * a_prev
        b_prev, b_cur = den * b_cur, den * b_cur + num * b_prev
    scale = 1.0 / b_cur
    return a_prev * scale, a_cur * scale, b_prev * scale, jnp.ones_like(x)


def _betacf_fixed(a, b, x, iterations):
    """The continued fraction of I_x(a, b) (Numerical Recipes' ``betacf``) with a
    fixed number of iterations.

    Forward (Wallis) recurrence with one division per iteration, rescaled every
    iteration. Returns (value, converged): converged says the last iteration
    changed the value by less than ``_CF_TOL``.
    """
    state = _cf_start(a, b, x)
    h = state[1] / state[3]
    converged = jnp.zeros(x.shape, bool)
    for m in range(1, iterations + 1):
        state = _cf_iterate(a, b, x, float(m), state)
        converged = jnp.abs(state[1] - h) <= _CF_TOL * jnp.abs(state[1])
        h = state[1]
    return h, converged & jnp.isfinite(h)


def _betacf(a, b, x):
    """The continued fraction of I_x(a, b), iterated until each element converged."""
    state = _cf_start(a, b, x)
    h = state[1] / state[3]
    done = jnp.zeros(x.shape, bool)

    def cond(carry):
        m, _, _, done = carry
        return (m < _CF_MAX_ITER) & ~jnp.all(done)

    def body(carry):
        m, state, h, done = carry
        for i in range(_CF_UNROLL):
            state = _cf_iterate(a, b, x, m + i, state)
            h_new = jnp.where(done, h, state[1])
            done = done | (jnp.abs(h_new - h) <= _CF_TOL * jnp.abs(h_new))
            h = h_new
        return m + _CF_UNROLL, state, h, done

    carry = (jnp.float32(1.0), state, h, done)
    _, _, h, _ = jax.lax.while_loop(cond, body, carry)
    return h


def _betainc_and_logpdf(a, b, x):
    """(I_x(a, b), log density at x) for a, b > 0 and 0 < x < 1, float32."""
    lpf = _log_prefactor(a, b, x)
    flip = x > (a + 1.0) / (a + b + 2.0)
    aa = jnp.where(flip, b, a)
    bb = jnp.where(flip, a, b)
    xx = jnp.where(flip, 1.0 - x, x)
    tail = jnp.exp(lpf) * _betacf(aa, bb, xx) / aa
    value = jnp.where(flip, 1.0 - tail, tail)
    logpdf = lpf - jnp.log(x) - jnp.log1p(-x)
    return jnp.clip(value, 0.0, 1.0), logpdf


def betainc(a: jax.Array, b: jax.Array, x: jax.Array) -> jax.Array:
    """Regularised incomplete beta function I_x(a, b), elementwise, float32.

    Unlike ``jax.scipy.special.betainc`` in float32, stays accurate (about 1e-6
    absolute) for shapes in the thousands.
    """
    a, b, x = jnp.broadcast_arrays(
        jnp.asarray(a, jnp.float32),
        jnp.asarray(b, jnp.float32),
        jnp.asarray(x, jnp.float32),
    )
    a = jnp.maximum(a, _MIN_SHAPE)
    b = jnp.maximum(b, _MIN_SHAPE)
    inside = (x > 0.0) & (x < 1.0)
    value, _ = _betainc_and_logpdf(a, b, jnp.where(inside, x, 0.5))
    return jnp.where(inside, value, jnp.where(x >= 1.0, 1.0, 0.0))


_PPF_MAX_ITER = 40


def _ppf_initial_guess(q, a, b, small_shapes: bool = True):
    """Starting point of Numerical Recipes' ``invbetai`` (3rd ed., §6.14).

    ``small_shapes=False`` skips the formula for shapes below 1 (the caller knows
    there are none): the other elements get the same bits either way.
    """
    # Both shapes >= 1: normal approximation with a skewness correction.
    pp = jnp.where(q < 0.5, q, 1.0 - q)
    t = jnp.sqrt(-2.0 * jnp.log(pp))
    z = (2.30753 + t * 0.27061) / (1.0 + t * (0.99229 + t * 0.04481)) - t
    z = jnp.where(q < 0.5, -z, z)
    al = (z * z - 3.0) / 6.0
    a1 = jnp.maximum(a, 1.0)
    b1 = jnp.maximum(b, 1.0)
    inv_a = 1.0 / jnp.maximum(2.0 * a1 - 1.0, 1.0)
    inv_b = 1.0 / jnp.maximum(2.0 * b1 - 1.0, 1.0)
    h = 2.0 / (inv_a + inv_b)
    w = z * jnp.sqrt(jnp.maximum(al + h, 0.0)) / h - (inv_b - inv_a) * (
        al + 5.0 / 6.0 - 2.0 / (3.0 * h)
    )
    x_big = a / (a + b * jnp.exp(jnp.clip(2.0 * w, -80.0, 80.0)))
    if not small_shapes:
        return jnp.clip(x_big, 1e-30, 1.0 - 6e-8)
    # A shape below 1: power-law tails.
    lna = jnp.log(a / (a + b))
    lnb = jnp.log(b / (a + b))
    ta = jnp.exp(a * lna) / a
    tb = jnp.exp(b * lnb) / b
    tw = ta + tb
    x_small = jnp.where(
        q < ta / tw,
        jnp.exp(jnp.log(a * tw * q) / a),
        1.0 - jnp.exp(jnp.log(b * tw * (1.0 - q)) / b),
    )
    x = jnp.where((a >= 1.0) & (b >= 1.0), x_big, x_small)
    return jnp.clip(x, 1e-30, 1.0 - 6e-8)


_PPF_FAST_CF_TERMS = 10


def _halley_step(a, b, x, value, logpdf, q):
    """x - (I_x - q) / pdf with Halley's curvature correction."""
    newton = (value - q) * jnp.exp(-logpdf)
    curv = (a - 1.0) / x - (b - 1.0) / (1.0 - x)
    halley = jnp.clip(newton * curv, -1.0, 1.0)
    return x - newton / (1.0 - 0.5 * jnp.where(jnp.isnan(halley), 0.0, halley))


def _ppf_fast(q, a, b, small_shapes: bool = True):
    """Beta quantiles at a fixed cost, with a flag saying where they are exact.

    Two Halley steps from the initial guess, each on a continued fraction of
    ``_PPF_FAST_CF_TERMS`` terms. An element is certified when both fractions
    converged and the last step was below 1e-2 of the distance to the nearer end
    of (0, 1): Halley converges cubically, so its result is then good to ~1e-6 of
    that distance.
    Small shapes (the bulk of a Thompson posterior) pass; the rest does not.
    """
    at_peak = _log_prefactor_at_peak(a, b)
    flip_at = (a + 1.0) / (a + b + 2.0)
    x = _ppf_initial_guess(jnp.clip(q, 1e-30, 1.0 - 6e-8), a, b, small_shapes)
    certified = jnp.ones(x.shape, bool)
    for _ in range(2):
        lpf = _log_prefactor(a, b, x, at_peak)
        flip = x > flip_at
        aa = jnp.where(flip, b, a)
        bb = jnp.where(flip, a, b)
        xx = jnp.where(flip, 1.0 - x, x)
        cf, cf_ok = _betacf_fixed(aa, bb, xx, _PPF_FAST_CF_TERMS)
        tail = jnp.exp(lpf) * cf / aa
        value = jnp.where(flip, 1.0 - tail, tail)
        logpdf = lpf - jnp.log(x) - jnp.log1p(-x)
        x_new = _halley_step(a, b, x, value, logpdf, q)
        ok = cf_ok & (x_new > 0.0) & (x_new < 1.0)
        certified &= ok
        small = jnp.abs(x_new - x) <= 1e-2 * jnp.minimum(x_new, 1.0 - x_new)
        x = jnp.where(ok, x_new, x)
    return x, certified & small


def _ppf_robust(q, a, b, x0):
    """Beta quantiles by safeguarded Halley steps from x0, iterated to convergence."""
    lo = jnp.zeros_like(x0)
    hi = jnp.ones_like(x0)
    done = jnp.zeros(x0.shape, bool)

    def cond(state):
        it, _, _, _, done = state
        return (it < _PPF_MAX_ITER) & ~jnp.all(done)

    def body(state):
        it, x, lo, hi, done = state
        value, logpdf = _betainc_and_logpdf(a, b, x)
        err = value - q
        lo = jnp.where(err < 0.0, x, lo)
        hi = jnp.where(err < 0.0, hi, x)
        x_new = _halley_step(a, b, x, value, logpdf, q)
        stalled = x_new == x
        inside = ((x_new > lo) & (x_new < hi)) | stalled
        x_new = jnp.where(inside, x_new, 0.5 * (lo + hi))
        converged = stalled | (err == 0.0)
        # Halley converges cubically: once a step is this small, its result is
        # exact to float32 precision.
        small = jnp.abs(x_new - x) <= 1e-3 * jnp.minimum(x_new, 1.0 - x_new)
        converged |= inside & small
        converged |= hi - lo <= 1e-7 * jnp.maximum(x_new, 1e-3)
        x = jnp.where(done, x, x_new)
        return it + 1, x, lo, hi, done | converged

    state = (jnp.int32(0), x0, lo, hi, done)
    _, x, _, _, _ = jax.lax.while_loop(cond, body, state)
    return x


def beta_ppf(q: jax.Array | float, a: jax.Array, b: jax.Array) -> jax.Array:
    """Inverse CDF of Beta(a, b) at probability q, elementwise (broadcasting).

    Matches ``scipy.stats.beta.ppf`` within 1e-4 (float32; about 1e-6 typical).
    Every element first gets two Halley steps on a short continued fraction (a
    fixed cost); the elements that this does not settle (large shapes, poor
    starting points) are packed into a small buffer and solved there by
    safeguarded Halley steps on the converged :func:`betainc`, so the cost of a
    few hard elements is not paid by all. Each element's value depends only on its
    own (q, a, b).
    """
    q, a, b = jnp.broadcast_arrays(
        jnp.asarray(q, jnp.float32),
        jnp.asarray(a, jnp.float32),
        jnp.asarray(b, jnp.float32),
    )
    shape = q.shape
    q, a, b = q.reshape(-1), a.reshape(-1), b.reshape(-1)
    n = q.shape[0]
    if n == 0:
        return q.reshape(shape)
    if n == 1:
        # XLA compiles one-element arrays differently; the last bit of a value must
        # not depend on how many others were computed beside it. Pad with a
        # different element (one XLA cannot fold into the first).
        pad = jnp.ones(1, jnp.float32)
        x = beta_ppf(
            jnp.concatenate([q, 0.5 * pad]),
            jnp.concatenate([a, pad]),
            jnp.concatenate([b, pad]),
        )
        return x[:1].reshape(shape)
    a = jnp.maximum(a, _MIN_SHAPE)
    b = jnp.maximum(b, _MIN_SHAPE)
    qc = jnp.clip(q, 0.0, 1.0)
    x, certified = jax.lax.cond(
        jnp.any((a < 1.0) | (b < 1.0)),
        lambda: _ppf_fast(qc, a, b, small_shapes=True),
        lambda: _ppf_fast(qc, a, b, small_shapes=False),
    )
    certified |= (qc <= 0.0) | (qc >= 1.0) | jnp.isnan(q)
    capacity = max(2, min(n, n // 16 + 64))

    def cond(state):
        return ~jnp.all(state[1])

    def body(state):
        x, certified = state
        idx = _pending_slots(~certified, capacity)
        idx_c = jnp.minimum(idx, n - 1)
        sub = _ppf_robust(qc[idx_c], a[idx_c], b[idx_c], x[idx_c])
        x = x.at[idx].set(sub, mode="drop")
        certified = certified.at[idx].set(True, mode="drop")
        return x, certified

    x, _ = jax.lax.while_loop(cond, body, (x, certified))
    x = jnp.where(qc <= 0.0, 0.0, jnp.where(qc >= 1.0, 1.0, x))
    x = jnp.where(jnp.isnan(q), jnp.nan, x)
    return x.reshape(shape)


# --------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------


def argmax_first(x: jax.Array, axis: int = -1) -> jax.Array:
    """Index of the maximum along ``axis``, the smallest one on ties (int32).

    Computed as the max, then the smallest index holding it: about twice as fast as
    ``jnp.argmax`` on CPU. ``x`` must hold no NaN.
    """
    x = jnp.asarray(x)
    axis = axis % x.ndim
    n = x.shape[axis]
    top = jnp.max(x, axis=axis, keepdims=True)
    shape = [1] * x.ndim
    shape[axis] = n
    index = jnp.arange(n, dtype=jnp.int32).reshape(shape)
    return jnp.min(jnp.where(x == top, index, n), axis=axis)


def _ordered_key(x: jax.Array) -> jax.Array:
    """float32 -> int32 whose order is the floats' order (-0 just below +0)."""
    bits = jax.lax.bitcast_convert_type(x, jnp.int32)
    return bits ^ ((bits >> 31) & jnp.int32(0x7FFFFFFF))


def _key_value(key: jax.Array) -> jax.Array:
    """The inverse of :func:`_ordered_key`."""
    return jax.lax.bitcast_convert_type(
        key ^ ((key >> 31) & jnp.int32(0x7FFFFFFF)), jnp.float32
    )


def order_statistics(x: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
    """The k-th and (k+1)-th smallest values along the last axis (0-based k).

    Exactly ``np.sort(x, -1)[..., k]`` and ``[..., k + 1]`` (the last entry when
    k + 1 is past the end), found without sorting: a bisection over the floats'
    32-bit patterns (32 counting passes), then one pass for the next value. On
    CPU about 1.5x as fast as ``lax.top_k`` for k ~ 150 of 3000. ``x`` must
    hold no NaN.
    """
    x = jnp.asarray(x, jnp.float32)
    n = x.shape[-1]
    if not 0 <= k < n:
        raise ValueError(f"k = {k} out of range for {n} values")
    key = _ordered_key(x)
    lo = jnp.min(key, axis=-1)
    hi = jnp.max(key, axis=-1)

    # Invariant: the k-th smallest key lies in [lo, hi].
    def halve(_, bounds):
        lo, hi = bounds
        mid = (lo & hi) + ((lo ^ hi) >> 1)  # floor((lo + hi) / 2) without overflow
        count = jnp.sum((key <= mid[..., None]).astype(jnp.int32), axis=-1)
        left = count >= k + 1
        return jnp.where(left, lo, mid + 1), jnp.where(left, mid, hi)

    kth, _ = jax.lax.fori_loop(0, 32, halve, (lo, hi))
    if k + 1 >= n:
        return _key_value(kth), _key_value(kth)
    at_most = jnp.sum((key <= kth[..., None]).astype(jnp.int32), axis=-1)
    above = jnp.min(
        jnp.where(key > kth[..., None], key, jnp.iinfo(jnp.int32).max), axis=-1
    )
    nxt = jnp.where(at_most >= k + 2, kth, above)
    return _key_value(kth), _key_value(nxt)
