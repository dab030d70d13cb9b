"""Random words for the exact samplers: Threefry-2x32 on counters.

Threefry-2x32 (20 rounds, the generator behind ``jax.random``), written out with
``jnp`` integer ops and evaluated on a counter ``(element index, stream | try)``
under each row's key; bit-identical to ``jax.extend.random.threefry_2x32``. A
row's words depend only on its key, so results never depend on batch size, batch
order or device count. The streams below keep the uses of one key apart.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["key_words", "threefry2x32", "uniform_bits", "uniform_rows"]

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
