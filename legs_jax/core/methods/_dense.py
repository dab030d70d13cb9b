"""Thompson sampling on a Beta posterior over all K grasps of a pose (dense state).

Shared by BORGES (K=2000) and LEGS(-AS); the state holds α, β for every grasp.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from legs_jax.core.methods.base import (
    Config,
    Ctx,
    argmax_first,
    best_estimates,
    beta_counts,
    gather_at,
    gather_rows,
    posterior_prior,
    prune_mask,
    thompson_draw,
    updated_row,
)


class DenseState(NamedTuple):
    alpha: jax.Array  # [B, P, K] f32 Beta α (prior offset included)
    beta: jax.Array  # [B, P, K] f32 Beta β
    attempted: jax.Array  # [B, P, K] bool tried at least once
    removed: jax.Array | None  # [B, P, K] bool pruned (LEGS(-AS)), else None


def init(ctx: Ctx, cfg: Config, *, removable: bool) -> DenseState:
    q = ctx.tables.q[ctx.ot]  # [B, P, K]
    valid = ctx.tables.valid[ctx.ot]
    alpha, beta = posterior_prior(q, ctx.hp)
    alpha = jnp.where(valid, alpha, 1.0)
    beta = jnp.where(valid, beta, 1.0)
    attempted = jnp.zeros(q.shape, bool)
    removed = jnp.zeros(q.shape, bool) if removable else None
    return DenseState(alpha, beta, attempted, removed)


def _mask_row(st: DenseState, ctx: Ctx, s: jax.Array) -> jax.Array:
    m = gather_rows(ctx.tables.valid, ctx.ot, s)  # [B, K]
    if st.removed is not None:
        m = m & ~gather_at(st.removed, s)
    return m


def _mask(st: DenseState, ctx: Ctx) -> jax.Array:
    m = ctx.tables.valid[ctx.ot]  # [B, P, K]
    if st.removed is not None:
        m = m & ~st.removed
    return m


def select(st: DenseState, ctx: Ctx, cfg: Config, s, key):
    a = gather_at(st.alpha, s)
    b = gather_at(st.beta, s)
    mask = _mask_row(st, ctx, s)
    i = thompson_draw(key, a, b, mask)
    return i, i, (a, b, mask)


def update(st, ctx: Ctx, cfg: Config, s, grasp, slot, reward, live):
    """The Beta update of column ``slot`` of pose s (any state with ``alpha``,
    ``beta`` and ``attempted`` [B, P, N]: a grasp id here, a slot in _slots)."""
    bi = jnp.arange(s.shape[0])
    was = st.attempted[bi, s, slot]
    win = (live & reward).astype(jnp.float32)
    loss = (live & ~reward).astype(jnp.float32)
    st = st._replace(
        alpha=st.alpha.at[bi, s, slot].add(win),
        beta=st.beta.at[bi, s, slot].add(loss),
        attempted=st.attempted.at[bi, s, slot].set(was | live),
    )
    return st, live & ~was


def best_mean(a, b, mask):
    """[B] the grasp of highest posterior mean α / (α + β) over ``mask`` [B, K]
    (ties: lowest id), -1 where the mask is empty."""
    best = argmax_first(jnp.where(mask, a / (a + b), -jnp.inf))
    return jnp.where(jnp.any(mask, axis=-1), best, -1)


def recommend(st: DenseState, ctx: Ctx, cfg: Config, s):
    a = gather_at(st.alpha, s)
    b = gather_at(st.beta, s)
    return best_mean(a, b, _mask_row(st, ctx, s))


def recommend_updated(rows, ctx: Ctx, cfg: Config, s, slot, reward, live):
    a, b, mask = rows
    win = (live & reward).astype(jnp.float32)
    a = updated_row(a, slot, win)
    b = updated_row(b, slot, live.astype(jnp.float32) - win)
    return best_mean(a, b, mask)


def recommend_init(st: DenseState, ctx: Ctx, cfg: Config):
    """Argmax q over the candidates (all valid grasps at step 0)."""
    nv = ctx.tables.n_valid[ctx.ot]  # [B, P]
    return jnp.where(nv > 0, ctx.tables.order[ctx.ot][..., 0], -1)


def estimates(st: DenseState, ctx: Ctx, cfg: Config):
    mean = st.alpha / (st.alpha + st.beta)
    return best_estimates(mean, _mask(st, ctx), st.attempted)


def counts(st: DenseState, ctx: Ctx, cfg: Config):
    succ, fail = beta_counts(st.alpha, st.beta, ctx.tables.q[ctx.ot], ctx.hp)
    ids = jnp.broadcast_to(jnp.arange(st.alpha.shape[-1], dtype=jnp.int32), succ.shape)
    return succ, fail, st.attempted, ids


def candidates(st: DenseState, ctx: Ctx, cfg: Config):
    return _mask(st, ctx)


def prune(st: DenseState, ctx: Ctx, cfg: Config, s, live):
    """LEGS(-AS): remove B from pose s; no refill."""
    bi = jnp.arange(s.shape[0])
    a = st.alpha[bi, s]
    b = st.beta[bi, s]
    att = st.attempted[bi, s]
    active = _mask_row(st, ctx, s)
    gone = prune_mask(a, b, att, active, ctx.hp.delta, ctx.hp.gamma)
    gone = gone & live[:, None]
    removed = st.removed.at[bi, s].set(st.removed[bi, s] | gone)
    return st._replace(removed=removed), jnp.sum(gone, axis=-1, dtype=jnp.int32)


# The functions a method built on this state shares (besides ``init``).
_SHARED = (select, update, recommend, recommend_updated, recommend_init)
FUNCTIONS = {f.__name__: f for f in (*_SHARED, estimates, candidates, counts)}
