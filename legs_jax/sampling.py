"""Exact random variates and quantiles used by the engine.

Every sampler takes one key per row (``keys: [B]``) and the row's values depend only
on its own key and parameters, so results never depend on batch size, batch order or
device count.

(Baseline implementation: correct and exact but not yet tuned for speed.)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["beta_rows", "beta_ppf", "dirichlet_lower_bound"]


def beta_rows(keys: jax.Array, a: jax.Array, b: jax.Array) -> jax.Array:
    """Exact Beta(a, b) draws, one key per row.

    Args:
      keys: [B] typed PRNG keys (consumed).
      a, b: [B, N] shape parameters, > 0 (float32).
    Returns:
      [B, N] float32 draws in [0, 1].
    """
    return jax.vmap(lambda k, a_, b_: jax.random.beta(k, a_, b_))(keys, a, b)


def beta_ppf(q: jax.Array | float, a: jax.Array, b: jax.Array) -> jax.Array:
    """Inverse CDF of Beta(a, b) at probability q, elementwise (broadcasting).

    Bisection on the regularised incomplete beta function; matches
    ``scipy.stats.beta.ppf`` to well under 1e-4.
    """
    a = jnp.asarray(a, jnp.float32)
    b = jnp.asarray(b, jnp.float32)
    q = jnp.asarray(q, jnp.float32)
    shape = jnp.broadcast_shapes(q.shape, a.shape, b.shape)
    lo = jnp.zeros(shape, jnp.float32)
    hi = jnp.ones(shape, jnp.float32)

    def body(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        below = jax.scipy.special.betainc(a, b, mid) < q
        return jnp.where(below, mid, lo), jnp.where(below, hi, mid)

    lo, hi = jax.lax.fori_loop(0, 30, body, (lo, hi))
    return 0.5 * (lo + hi)


def dirichlet_lower_bound(
    keys: jax.Array,
    counts: jax.Array,
    observed: jax.Array,
    values: jax.Array,
    delta: jax.Array | float,
    num_samples: int = 3000,
) -> jax.Array:
    """The δ-quantile of p' = Σ_s v_s λ'_s with λ' ~ Dir(c_s + 1 observed, 1 unseen).

    SPEC §5. Unobserved poses get no bin of their own; one extra "unseen" bin with
    parameter 1 carries value 0.

    Args:
      keys: [B] typed PRNG keys (consumed).
      counts: [B, P] drop counts c_s.
      observed: [B, P] bool, pose observed so far.
      values: [B, P] p̂*_s, the estimated best success probability of each pose.
      delta: the quantile δ_stop (scalar or [B]).
      num_samples: M.
    Returns:
      [B] float32 lower bounds p̂_ℓ.
    """
    delta = jnp.broadcast_to(jnp.asarray(delta, jnp.float32), keys.shape)

    def one(key, c, obs, v, d):
        alpha = jnp.concatenate([jnp.where(obs, c + 1.0, 1.0), jnp.ones(1)])
        g = jax.random.gamma(key, alpha, shape=(num_samples, alpha.shape[0]))
        g = g * jnp.concatenate([obs, jnp.ones(1, bool)])
        lam = g / g.sum(axis=1, keepdims=True)
        p = lam[:, :-1] @ jnp.where(obs, v, 0.0)
        return jnp.quantile(p, d)

    return jax.vmap(one)(keys, counts.astype(jnp.float32), observed, values, delta)
