"""Exact Beta draws by Cheng's log-logistic rejection, in plain ``jnp`` (CPU and GPU).

:func:`beta_rows_v2` has the contract of :func:`legs_jax.core.sampling.beta_rows`
(one key per row, element ``j`` of a row depends only on the row's key, ``j`` and its
own shapes; the same shapes in and out; float32 draws in [0, 1]) but a different
algorithm, so a different random stream.

Algorithm: Cheng (1978), "Generating beta variates with nonintegral shape
parameters", CACM 21(4), algorithm BA with the parameter choices of BB
(min(a, b) > 1) and BC (min(a, b) <= 1), in one code path: the region only changes
per-element constants, so a batch mixing both costs one pass. A try takes two
24-bit uniforms U1, U2 (the two halves of one Threefry-2x32 block) and

    V = log(U1 / (1 - U1)) / lam,   W = a0 exp(V),
    accept if  al log(al / (b0 + W)) + (a0 + lam) V - log 4 >= log(U1^2 U2),
    return W / (b0 + W)  (or b0 / (b0 + W) when a0 is the second shape),

with al = a + b; BB: a0 = min(a, b), lam = sqrt((2 a b - al) / (al - 2)); BC:
a0 = max(a, b), lam = min(a, b). The squeezes of BB and BC are left out (a vector
computes every branch anyway); they never change which tries are accepted.
Acceptance per try is 0.85-1.0 for shapes in [1, 3], about 0.9 for large
symmetric shapes, 0.68 for (1, large), 0.3 for (0.05, large).

Float32 care (the formulas are the exact ones, rearranged; see :func:`_try`):

- V comes from the integers: U1 = (2k + 1) / 2^25, so U1 / (1 - U1) =
  (2k + 1) / (2^25 - 2k - 1): both sides odd integers, never 0 (a float32
  U1 = (k + 1/2) / 2^24 rounds to 1 at the top of the range, and 1 - U1 to 0).
- The test is written in y = V (BB) or -V (BC) and E = expm1(y) as
  c_lin y - (a + b) log1p(c E) - log 4 with c = min(a, b) / (a + b): in BC the
  O(a + b) terms cancel analytically (c_lin = 0), in BB only O(sqrt(a + b)) terms
  are left to cancel (shapes 1e4 keep the test good to about 1e-5 absolute, not
  1e-3), 1 + c E never loses its digits (c <= 1/2), and nothing overflows (y is up
  to +-350 for shapes 0.05; beyond y = 80 the log is taken of a rescaled sum).
- The draw is c e^y / (1 + c E) or c' / (1 + c E): ratios of sums of positive
  terms, so tiny draws keep their relative precision; the second shape's draw is
  computed directly, not as 1 - x.

Uniforms have 24 bits (Threefry words' top bits): the proposal's quantiles are
exact to 2^-24, its tails cut at mass 2^-24 and the acceptance probability
resolved to 2^-24, so every CDF is within a few 2^-24 ~ 6e-8 of Beta(a, b),
float32's own resolution. (16-bit uniforms would leave errors of 1.5e-5, which
the 3.7e10 draws of a full sweep could see; 24 bits cannot be seen.)

Values that round to 0 or 1: a draw is the float32 nearest to the exact one
(computed to a few ulps), so it is 0 only when the exact draw is below the
float32 normal range (about 1e-38; draws there may flush to 0) and 1 only when it
is within 2^-25 of 1. Both happen with real probability only for shapes below 1
(e.g. 2 % of Beta(0.05, 1e4) draws are 0, 69 % of Beta(1e4, 0.05) draws are 1).

Retries: try 0 of every element runs in bulk, in one pass (about 10 % of
posterior-like draws are rejected). The rejected ones are packed (first level,
:func:`legs_jax.core.sampling._pending_slots`) into a buffer of ``capacity``
slots (total / 10 + 64 by default; more pending elements take further passes) and
get try 1 there; the ones rejected again are packed into a second buffer
(``capacity2`` slots, capacity / 8 + 64) and take tries 2, 3, ... until every
one is accepted. Try t of element j uses the counter (j, stream << 24 | t), and
an element always keeps the first accepted try of its own sequence 0, 1, 2, ...,
so the draws do not depend on the buffer sizes, on the batch or on the device
count.

Speed (2-core AVX2 CPU, per CPU second, K = 2000 Thompson-step shapes): try 0 alone
is 1.0-1.1x as fast as the old sampler's try 0, but twice as many tries are
rejected, and the packed retry is about half of either sampler's time; end to end
this sampler is 0.95-1.08x the old one and 1.7-2.0x NumPy's ``Generator.beta`` per
core. Per element of a [64, 2000] batch: Threefry words about 3 ns, try 0 in bulk
about 13 ns (XLA on CPU compiles it to seven fusions, the per-element constants in
five of them), the whole sampler 23-25 ns, so the retry of the ~9 % rejected costs
about 10 ns per element of the batch. Retries in fixed slots per 32-element word
(no prefix sums) kept the bits but were no faster: one try costs about 15 ns a slot.
Since the packing marks its valid slots without reading the pending count, finding
the slots is twice as fast; on a 2-core Intel Xeon (AVX-512, one core) the whole
sampler takes about 15 ns an element, the retry about 5 of them
(``docs/performance.md``). Compiled for 512-bit vectors, as the engine compiles its
simulations on such a processor, it takes about 12.5 ns, with the same bits.
On CPU, XLA contracts products and sums into fused multiply-adds fusion by fusion,
so a change of the retry's program can move the bulk pass's last bits: a change
must be compared bit for bit with the jitted sampler before it.

The engine's Thompson methods (LEGS, BORGES:
:func:`legs_jax.core.methods.base.thompson_draw` and the slot methods' ``select``)
draw with this sampler. The sweep's manifests name it
(``"beta_sampler"`` in their configuration, :data:`SAMPLER_VERSION`); results whose
manifests name none were made with :func:`legs_jax.core.sampling.beta_rows`
(:data:`PREVIOUS_SAMPLER_VERSION`), which stays for comparison and the benchmark.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from legs_jax.core.sampler_versions import (  # noqa: F401 - re-exported
    PREVIOUS_SAMPLER_VERSION,
    SAMPLER_VERSION,
)
from legs_jax.core.sampling import (
    _beta_inputs,
    _finish_pending,
    threefry2x32,
)

__all__ = ["PREVIOUS_SAMPLER_VERSION", "SAMPLER_VERSION", "beta_rows_v2"]


# Counter stream of this sampler: the high byte of the second counter word (the
# streams of legs_jax.core.sampling use 0-7); the try number fills the low 24 bits.
_STREAM = 8
_STREAM_SHIFT = 24
# Shapes below this are treated as this (as in legs_jax.core.sampling).
_MIN_SHAPE = 1e-30
_LOG4 = math.log(4.0)
_LOG2 = math.log(2.0)


def _params(a, b):
    """Per-element constants of algorithm BA: (sign / lam, c, c', c_lin, a + b,
    whether a's draw is the c part); see :func:`_try`."""
    a = jnp.maximum(a, _MIN_SHAPE)
    b = jnp.maximum(b, _MIN_SHAPE)
    mn = jnp.minimum(a, b)
    mx = jnp.maximum(a, b)
    al = a + b
    small = mn <= 1.0  # BC; else BB
    # BB: lam^2 = (2ab - al) / (al - 2) = 1 + 2 (a - 1)(b - 1) / (a + b - 2),
    # written in the excesses over 1 (no cancellation; 1 at a = b = 1).
    e1 = jnp.maximum(mn - 1.0, 0.0)
    e2 = jnp.maximum(mx - 1.0, 0.0)
    lam_bb = jnp.sqrt(1.0 + 2.0 * e1 * e2 / jnp.maximum(e1 + e2, _MIN_SHAPE))
    signed_inv_lam = jnp.where(small, -1.0 / mn, 1.0 / lam_bb)
    c_lin = jnp.where(small, 0.0, mn + lam_bb)
    return signed_inv_lam, mn / al, mx / al, c_lin, al, a <= b


def _expm1_neg(s, e):
    """expm1(-s) for s >= 0 given e = exp(-s): a Taylor polynomial below log 2
    (relative error below 1e-8), e - 1 (exact) above."""
    near = s < _LOG2
    t = jnp.where(near, s, 0.0)
    poly = jnp.float32(1.0 / 362880.0)
    for k in (40320.0, 5040.0, 720.0, 120.0, 24.0, 6.0, 2.0, 1.0):
        poly = 1.0 / k - t * poly
    return jnp.where(near, -t * poly, e - 1.0)


def _try(params, w0, w1):
    """One try from the words (w0, w1): the draw where accepted, else -1.

    With y = V (BB) or -V (BC), c = min(a, b) / (a + b), c' = max(a, b) / (a + b)
    and E = expm1(y), the test of BA is

        c_lin y - (a + b) log(1 + c E) - log 4 >= log(U1^2 U2),

    c_lin = a0 + lam (BB) or 0 (BC, where a0 + lam = a + b cancels exactly), and
    the draw of the shape min(a, b) ("the c part") is c e^y / (1 + c E), the
    other's c' / (1 + c E). (BB: a0 = min, so these are W / (b0 + W) and
    b0 / (b0 + W); BC: a0 = max, the same divided through by e^V.) For y > 80
    (BC only), 1 + c E = e^y (c + c' e^-y) is used instead, which cannot
    overflow.
    """
    signed_inv_lam, c, c2, c_lin, al, a_is_c = params
    k1 = w0 >> jnp.uint32(8)
    k2 = w1 >> jnp.uint32(8)
    odd1 = (k1 * jnp.uint32(2) + jnp.uint32(1)).astype(jnp.float32)  # 2^25 U1
    rest1 = (jnp.uint32(1 << 25) - jnp.uint32(1) - k1 * jnp.uint32(2)).astype(
        jnp.float32
    )  # 2^25 (1 - U1)
    odd2 = (k2 * jnp.uint32(2) + jnp.uint32(1)).astype(jnp.float32)  # 2^25 U2
    y = jnp.log(odd1 / rest1) * signed_inv_lam
    s = jnp.abs(y)
    e = jnp.exp(-s)
    em = _expm1_neg(s, e)
    up = y > 0.0
    big_e = jnp.where(up, -em / e, em)  # expm1(y)
    big = y > 80.0
    ce = c * big_e
    arg = jnp.where(big, c + c2 * e, jnp.maximum(1.0 + ce, _MIN_SHAPE))
    # log(1 + c E): Goldberg's log1p (the correction term), or y + log(arg).
    log_term = jnp.log(arg) + jnp.where(big, y, -((arg - 1.0) - ce) / arg)
    test = c_lin * y - al * log_term - jnp.float32(_LOG4)
    z = odd1 * odd1 * odd2 * jnp.float32(2.0**-75)  # U1^2 U2 (no underflow)
    ok = z <= jnp.exp(test)
    exp_y = jnp.where(big, 1.0, jnp.where(up, 1.0 + big_e, e))  # e^y (scaled)
    num = jnp.where(a_is_c, c * exp_y, c2 * jnp.where(big, e, 1.0))
    return jnp.where(ok, num / arg, jnp.float32(-1.0))


def _counter(t):
    return jnp.uint32(_STREAM << _STREAM_SHIFT) + jnp.asarray(t, jnp.uint32)


def _round64(c: float) -> int:
    """A multiple of 64 (XLA's CPU loops run scalar over odd lengths), >= 64."""
    return max(64, -(-int(c) // 64) * 64)


def beta_rows_v2(keys: jax.Array, a: jax.Array, b: jax.Array) -> jax.Array:
    """Exact Beta(a, b) draws, one key per row (Cheng's algorithm BA/BB/BC).

    Element j of a row draws from the counters (j, stream << 24 | try) under the
    row's key: try 0 of every element in bulk, the rejected ones in two packed
    retry buffers (see the module docstring). Same contract as
    :func:`legs_jax.core.sampling.beta_rows`, different random stream.

    Args:
      keys: [B] typed PRNG keys (consumed) or raw uint32 keys [B, 2].
      a, b: [B, N] shape parameters, > 0 (broadcast together; float32). Shapes
        below 1 are exact too.
    Returns:
      [B, N] float32 draws in [0, 1].
    """
    return _beta_rows(*_beta_inputs(keys, a, b))


def _first_tries(k0, k1, a, b):
    """Try 0 of every element in bulk, [B, N]: the draw where accepted, else -1
    (the elements the retry buffers take)."""
    col0 = jnp.arange(a.shape[1], dtype=jnp.uint32)[None]
    w0, w1 = threefry2x32(k0, k1, col0, _counter(0))
    return _try(_params(a, b), w0, w1)


def _beta_rows(k0, k1, a, b, *, capacity=None, capacity2=None):
    """:func:`beta_rows_v2` on key words [B, 1]; ``capacity`` and ``capacity2``
    (slots of the two retry buffers) change the work, never the values."""
    rows, n = a.shape
    total = rows * n
    x = _first_tries(k0, k1, a, b).reshape(-1)
    if total == 0:
        return x.reshape(rows, n)
    c1 = _round64(total / 10 + 64) if capacity is None else max(2, capacity)
    c2 = _round64(c1 / 8 + 64) if capacity2 is None else max(2, capacity2)
    a_flat, b_flat = a.reshape(-1), b.reshape(-1)
    key_pairs = jnp.concatenate([k0, k1], axis=1)  # [B, 2]

    def first_retry(x, idx):
        """Try 1 of the elements ``idx`` (``total`` where unused), then tries
        2, 3, ... of the ones it rejects, in the second buffer."""
        valid = idx < total
        idx_c = jnp.minimum(idx, total - 1)
        row = idx_c // n
        col = (idx_c - row * n).astype(jnp.uint32)
        kp = key_pairs[row]  # one gather for both words
        sa, sb = a_flat[idx_c], b_flat[idx_c]
        r0, r1 = kp[:, 0], kp[:, 1]
        v0, v1 = threefry2x32(r0, r1, col, _counter(1))
        got = _try(_params(sa, sb), v0, v1)
        buf = jnp.where(valid, got, 0.0)
        slot_data = jnp.stack(
            [
                jax.lax.bitcast_convert_type(sa, jnp.uint32),
                jax.lax.bitcast_convert_type(sb, jnp.uint32),
                r0,
                r1,
                col,
            ],
            axis=1,
        )  # [c1, 5]: one gather per slot of the second buffer
        buf = _finish_pending(buf, c2, lambda buf, j: _later_tries(buf, j, slot_data))
        return x.at[idx].set(buf, mode="drop")

    return _finish_pending(x, c1, first_retry).reshape(rows, n)


def _later_tries(buf, idx, slot_data):
    """Tries 2, 3, ... of the first buffer's slots ``idx`` (its length where
    unused), until every one is accepted."""
    m = buf.shape[0]
    valid = idx < m
    d = slot_data[jnp.minimum(idx, m - 1)]
    sa = jax.lax.bitcast_convert_type(d[:, 0], jnp.float32)
    sb = jax.lax.bitcast_convert_type(d[:, 1], jnp.float32)
    r0, r1, col = d[:, 2], d[:, 3], d[:, 4]
    params = _params(sa, sb)

    # (A loop, not unrolled: its state is a plain array, so that XLA emits vector
    # code for the tries.)
    def one_try(state):
        t, got = state
        v0, v1 = threefry2x32(r0, r1, col, _counter(t.astype(jnp.uint32)))
        return t + 1, jnp.where(got < 0.0, _try(params, v0, v1), got)

    init = (jnp.int32(2), jnp.where(valid, -1.0, 0.0).astype(jnp.float32))
    _, got = jax.lax.while_loop(lambda s: jnp.any(s[1] < 0.0), one_try, init)
    return buf.at[idx].set(got, mode="drop")
