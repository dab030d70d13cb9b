"""Exact random variates and quantiles used by the engine, fast on CPU and GPU.

Every sampler takes one key per row (``keys: [B]``) and a row's values depend only on
its own key and parameters, so results never depend on batch size, batch order or
device count. Within a row, element ``j`` of a draw depends only on the key, ``j``
and that element's parameters (not on the row's width).

How the samplers are built (all plain ``jnp`` ops, so XLA fuses them):

- Random words: Threefry-2x32 on counters (:mod:`legs_jax.core.bits`).
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
- Beta quantiles and the incomplete beta function: :mod:`legs_jax.core.special`
  (re-exported here).
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

from legs_jax.core.bits import (  # noqa: F401 - re-exported
    _STREAM_ACCEPT,
    _STREAM_BINS,
    _STREAM_BOOST,
    _STREAM_GAMMA_A,
    _STREAM_GAMMA_B,
    _STREAM_PAIR,
    _STREAM_SHIFT,
    _STREAM_UNIFORM,
    _counter_words,
    _open_unit,
    key_words,
    threefry2x32,
    uniform_bits,
    uniform_rows,
)
from legs_jax.core.packing import (  # noqa: F401 - re-exported
    _finish_pending,
    _materialized,
    _pending_slots,
)
from legs_jax.core.special import _MIN_SHAPE, beta_ppf, betainc  # noqa: F401

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


def _beta_inputs(keys: jax.Array, a, b):
    """(k0, k1, a, b) of a Beta sampler's arguments: the keys' two words, the
    shapes as float32 broadcast together (every Beta sampler takes them so)."""
    k0, k1 = key_words(keys)
    a = jnp.asarray(a, jnp.float32)
    b = jnp.asarray(b, jnp.float32)
    a, b = jnp.broadcast_arrays(a, b)
    return k0, k1, a, b


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
    k0, k1, a, b = _beta_inputs(keys, a, b)
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
