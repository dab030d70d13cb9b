"""Where every random draw of a rollout comes from.

A rollout is named by (seed, object, trial, rollout). Its key is

    rollout_key = fold_in(fold_in(fold_in(key(seed), object_id), trial), rollout)

and three independent streams hang off it:

- ``env_key = fold_in(rollout_key, 0)``: the environment (first drop, rewards,
  drops and topples). It does not depend on the method, so methods meet the same
  random numbers (common random numbers) as long as they visit the same states.
- ``method_key = fold_in(rollout_key, 1)``: the method's own draws (Thompson
  samples, ε-greedy coins).
- ``check_key = fold_in(rollout_key, 2)``: the Dirichlet stopping checks, so that
  recording checks never changes a trajectory.

Within a stream, step t (1..H) uses ``fold_in(stream_key, t)`` (the first drop uses
t = 0) and check number c (1, 2, ...) uses ``fold_in(check_key, c)``. Nothing
depends on batch size, batch order or device count.

``object_id`` is a stable integer per object: the index of the object in the sorted
catalogue, or :func:`object_id_from_name` for a user's own or synthetic problem.
"""

from __future__ import annotations

import hashlib

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core import sampling

__all__ = [
    "ENV_STREAM",
    "METHOD_STREAM",
    "CHECK_STREAM",
    "rollout_key",
    "rollout_keys",
    "rollout_key_data",
    "env_key",
    "method_key",
    "check_key",
    "step_keys",
    "object_id_from_name",
]

ENV_STREAM = 0
METHOD_STREAM = 1
CHECK_STREAM = 2


def rollout_key(seed: int, object_id: int, trial: int, rollout: int) -> jax.Array:
    """The typed key of one rollout (a scalar key array)."""
    k = jax.random.key(seed)
    k = jax.random.fold_in(k, object_id)
    k = jax.random.fold_in(k, trial)
    return jax.random.fold_in(k, rollout)


@jax.jit
def _rollout_keys(seed, object_ids, trials, rollouts):
    def one(o, t, r):
        k = jax.random.fold_in(jax.random.key(seed), o)
        return jax.random.fold_in(jax.random.fold_in(k, t), r)

    return jax.vmap(one)(object_ids, trials, rollouts)


def rollout_key_data(
    seed: int, object_ids: np.ndarray, trials: np.ndarray, rollouts: np.ndarray
) -> np.ndarray:
    """The raw uint32 words [B, 2] of :func:`rollout_keys` as a NumPy array
    (``jax.random.wrap_key_data`` gives the keys back).

    Computed on the host with NumPy (no JAX program to trace or compile): the key
    of ``seed`` is the words (0, seed), and ``fold_in(k, d)`` is Threefry-2x32 of
    the counter (0, d) under k, as in ``jax.random``; a test checks equality with
    :func:`rollout_keys`."""
    ids = [
        np.asarray(x, np.int64).reshape(-1).astype(np.uint32)
        for x in (object_ids, trials, rollouts)
    ]
    k0 = np.zeros(ids[0].shape, np.uint32)
    k1 = np.full(ids[0].shape, np.uint32(seed), np.uint32)
    zero = np.zeros_like(k0)
    for d in ids:
        k0, k1 = sampling.threefry2x32(k0, k1, zero, d, xp=np)
    return np.stack([k0, k1], axis=1)


def rollout_keys(
    seed: int, object_ids: np.ndarray, trials: np.ndarray, rollouts: np.ndarray
) -> jax.Array:
    """[B] rollout keys, elementwise over equal-length integer arrays.

    Equal to ``rollout_key(seed, object_ids[b], trials[b], rollouts[b])`` for every b.
    """
    as_u32 = lambda x: jnp.asarray(np.asarray(x, np.int64).astype(np.uint32))  # noqa: E731
    return _rollout_keys(
        jnp.uint32(seed), as_u32(object_ids), as_u32(trials), as_u32(rollouts)
    )


def env_key(key: jax.Array) -> jax.Array:
    """The environment stream of a rollout key (scalar or batched)."""
    return _fold(key, ENV_STREAM)


def method_key(key: jax.Array) -> jax.Array:
    """The method stream of a rollout key (scalar or batched)."""
    return _fold(key, METHOD_STREAM)


def check_key(key: jax.Array) -> jax.Array:
    """The stopping-check stream of a rollout key (scalar or batched)."""
    return _fold(key, CHECK_STREAM)


def step_keys(keys: jax.Array, t: jax.Array | int) -> jax.Array:
    """``fold_in(keys[b], t)`` for every b: the keys of step (or check) t."""
    return _fold(keys, t)


def _fold(keys: jax.Array, data) -> jax.Array:
    if keys.ndim == 0:
        return jax.random.fold_in(keys, data)
    return jax.vmap(jax.random.fold_in, in_axes=(0, None))(keys, data)


def object_id_from_name(name: str) -> int:
    """A stable id for an object outside the catalogue: a hash of its name mod 2**31."""
    digest = hashlib.sha256(name.encode("utf-8")).digest()
    return int.from_bytes(digest[:8], "little") % (2**31)
