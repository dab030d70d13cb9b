"""Thompson sampling on a Beta posterior over k slots per pose (active-set state).

Slot j of pose s holds one grasp id (or -1 when empty). Shared by BORGES (K=100),
whose slots are the fixed top-100 by q, and LEGS, whose slots are pruned and
refilled from the rest of the reservoir in descending q.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from legs_jax.core import beta_sampler
from legs_jax.core.methods._dense import update  # the same Beta update, per slot
from legs_jax.core.methods.base import (
    Config,
    Ctx,
    argmin_id_of_max,
    best_estimates,
    beta_counts,
    gather_at,
    posterior_prior,
    prune_mask,
    updated_row,
)


class SlotState(NamedTuple):
    alpha: jax.Array  # [B, P, k] f32 Beta α of each slot's grasp
    beta: jax.Array  # [B, P, k] f32 Beta β
    attempted: jax.Array  # [B, P, k] bool slot's grasp tried at least once
    gid: jax.Array  # [B, P, k] i32 grasp id in each slot, -1 empty
    next: jax.Array | None  # [B, P] i32 next refill position in the q order (LEGS)


def init(ctx: Ctx, cfg: Config, size: int, *, refill: bool) -> SlotState:
    """Slots hold the top-``size`` valid grasps of each pose by q."""
    order = ctx.tables.order[ctx.ot][..., :size]  # [B, P, size]
    nv = ctx.tables.n_valid[ctx.ot]  # [B, P]
    pos = jnp.arange(size, dtype=jnp.int32)
    gid = jnp.where(pos < nv[..., None], order, -1)
    q = jnp.take_along_axis(ctx.tables.q[ctx.ot], jnp.maximum(gid, 0), axis=-1)
    alpha, beta = posterior_prior(q, ctx.hp)
    filled = gid >= 0
    alpha = jnp.where(filled, alpha, 1.0)
    beta = jnp.where(filled, beta, 1.0)
    nxt = jnp.minimum(nv, size).astype(jnp.int32) if refill else None
    return SlotState(alpha, beta, jnp.zeros(gid.shape, bool), gid, nxt)


def select(st: SlotState, ctx: Ctx, cfg: Config, s, key):
    a = gather_at(st.alpha, s)
    b = gather_at(st.beta, s)
    gid = gather_at(st.gid, s)
    mask = gid >= 0
    phi = beta_sampler.beta_rows_v2(
        key, jnp.where(mask, a, 1.0), jnp.where(mask, b, 1.0)
    )
    grasp = argmin_id_of_max(phi, mask, gid, none=0)  # ties: lowest grasp id
    slot = jnp.argmax(gid == grasp[:, None], axis=-1).astype(jnp.int32)
    return grasp, slot, (a, b, gid)


def recommend(st: SlotState, ctx: Ctx, cfg: Config, s):
    a = gather_at(st.alpha, s)
    b = gather_at(st.beta, s)
    gid = gather_at(st.gid, s)
    return argmin_id_of_max(a / (a + b), gid >= 0, gid)


def recommend_updated(rows, ctx: Ctx, cfg: Config, s, slot, reward, live):
    a, b, gid = rows
    win = (live & reward).astype(jnp.float32)
    a = updated_row(a, slot, win)
    b = updated_row(b, slot, live.astype(jnp.float32) - win)
    return argmin_id_of_max(a / (a + b), gid >= 0, gid)


def recommend_init(st: SlotState, ctx: Ctx, cfg: Config):
    """Argmax q over the slots: the first grasp of the q order."""
    return st.gid[..., 0]


def estimates(st: SlotState, ctx: Ctx, cfg: Config):
    mean = st.alpha / (st.alpha + st.beta)
    return best_estimates(mean, st.gid >= 0, st.attempted)


def counts(st: SlotState, ctx: Ctx, cfg: Config):
    q = jnp.take_along_axis(ctx.tables.q[ctx.ot], jnp.maximum(st.gid, 0), axis=-1)
    succ, fail = beta_counts(st.alpha, st.beta, q, ctx.hp)
    return succ, fail, st.attempted & (st.gid >= 0), st.gid


def candidates(st: SlotState, ctx: Ctx, cfg: Config):
    B, P, _ = st.gid.shape
    dense = jnp.zeros((B, P, cfg.num_grasps + 1), bool)
    bi = jnp.arange(B)[:, None, None]
    pi = jnp.arange(P)[None, :, None]
    slot_ids = jnp.where(st.gid >= 0, st.gid, cfg.num_grasps)
    return dense.at[bi, pi, slot_ids].set(True)[..., : cfg.num_grasps]


def active_set(st: SlotState, ctx: Ctx, cfg: Config):
    return st.gid


def prune_refill(st: SlotState, ctx: Ctx, cfg: Config, s, live):
    """LEGS: remove B from pose s and refill the slots (slot order) from
    the queue in descending q; a slot stays empty (-1) once the queue is spent."""
    bi = jnp.arange(s.shape[0])
    a = st.alpha[bi, s]  # [B, k]
    b = st.beta[bi, s]
    att = st.attempted[bi, s]
    gid = st.gid[bi, s]
    gone = prune_mask(a, b, att, gid >= 0, ctx.hp.delta, ctx.hp.gamma, ids=gid)
    gone = gone & live[:, None]
    rank = jnp.cumsum(gone, axis=-1, dtype=jnp.int32) - 1  # [B, k]
    nxt = st.next[bi, s]  # [B]
    nv = ctx.tables.n_valid[ctx.ot, s]  # [B]
    pos = nxt[:, None] + rank
    fill = gone & (pos < nv[:, None])
    order_row = ctx.tables.order[ctx.ot, s]  # [B, K]
    new_gid = jnp.take_along_axis(
        order_row, jnp.clip(pos, 0, cfg.num_grasps - 1), axis=-1
    )
    new_gid = jnp.where(fill, new_gid, -1)
    q_row = ctx.tables.q[ctx.ot, s]  # [B, K]
    new_q = jnp.take_along_axis(q_row, jnp.maximum(new_gid, 0), axis=-1)
    new_a, new_b = posterior_prior(new_q, ctx.hp)
    n_gone = jnp.sum(gone, axis=-1, dtype=jnp.int32)
    st = SlotState(
        alpha=st.alpha.at[bi, s].set(jnp.where(gone, new_a, a)),
        beta=st.beta.at[bi, s].set(jnp.where(gone, new_b, b)),
        attempted=st.attempted.at[bi, s].set(att & ~gone),
        gid=st.gid.at[bi, s].set(jnp.where(gone, new_gid, gid)),
        next=st.next.at[bi, s].set(jnp.minimum(nxt + n_gone, nv)),
    )
    return st, n_gone


# The functions a method built on this state shares (besides ``init``).
_SHARED = (select, update, recommend, recommend_updated, recommend_init)
FUNCTIONS = {f.__name__: f for f in (*_SHARED, estimates, candidates, counts)}
