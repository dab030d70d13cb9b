"""Packing the few elements of a batch that still need work into a small buffer:
the pending mask packed into 32-bit words, slots found by prefix sums and a bit
search, so that a retry or a refinement loop runs on a handful of elements
rather than on the whole batch (the exact samplers' rejected tries, the Beta
quantile's uncertified elements)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__: list[str] = []


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
    # A slot past the last pending entry has every word end at or before it. (The
    # same test as slot < count, without the count: a scalar read in the pass below
    # made XLA's CPU loop over the slots three times as slow.)
    valid = block < nw
    block = jnp.minimum(block, nw - 1)  # (only past the last pending entry)
    # The two gathers in a pass of their own: in the same pass as the bit search
    # they turn its vector loop into a scalar one.
    word, first = jax.lax.optimization_barrier((words[block], before[block]))
    pos = block * 32 + _select_bit(word, slot - first)
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
