"""The constant rows: one fixed grasp per pose, no learning from it.

They still run in the environment (so successes and counters are real) and keep a
Beta posterior of their candidates for the Dirichlet check. Only the fixed grasp is
ever attempted, so the state is per pose: its counts, and the best prior mean of
the other candidates.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from legs_jax.core.methods.base import (
    Config,
    Ctx,
    argmin_id_of_max,
    gather_at,
    posterior_prior,
)


class FixedState(NamedTuple):
    choice: jax.Array  # [B, P] i32 the fixed grasp of each pose, -1 with none
    alpha: jax.Array  # [B, P] f32 Beta α of the fixed grasp
    beta: jax.Array  # [B, P] f32 Beta β of the fixed grasp
    attempted: jax.Array  # [B, P] bool fixed grasp tried
    other_best: jax.Array  # [B, P] f32 best prior mean of the other candidates


def prior_choice(ctx: Ctx, cfg: Config):
    """Dex-Net's row: argmax q over all valid grasps; (choice [B, P], candidates
    [B, P, K])."""
    t = ctx.tables
    nv = t.n_valid[ctx.ot]
    return jnp.where(nv > 0, t.order[ctx.ot][..., 0], -1), t.valid[ctx.ot]


def top_truth_choice(ctx: Ctx, cfg: Config):
    """The K100 upper bound: argmax p over the top ``cfg.top`` grasps by q;
    (choice [B, P], candidates [B, P, K]: those top grasps)."""
    t = ctx.tables
    nv = t.n_valid[ctx.ot]
    size = cfg.top
    pos = jnp.arange(size, dtype=jnp.int32)
    gid = jnp.where(pos < nv[..., None], t.order[ctx.ot][..., :size], -1)
    p_top = jnp.take_along_axis(t.p[ctx.ot], jnp.maximum(gid, 0), axis=-1)
    choice = argmin_id_of_max(p_top, gid >= 0, gid)
    B, P, _ = gid.shape
    cand = (
        jnp.zeros((B, P, cfg.num_grasps + 1), bool)
        .at[
            jnp.arange(B)[:, None, None],
            jnp.arange(P)[None, :, None],
            jnp.where(gid >= 0, gid, cfg.num_grasps),
        ]
        .set(True)[..., : cfg.num_grasps]
    )
    return choice, cand


def init(ctx: Ctx, cfg: Config, *, choose) -> FixedState:
    """``choose(ctx, cfg)``: the fixed grasp of each pose and the candidate set
    (:func:`prior_choice`, :func:`top_truth_choice`)."""
    q = ctx.tables.q[ctx.ot]  # [B, P, K]
    choice, cand = choose(ctx, cfg)
    a0, b0 = posterior_prior(q, ctx.hp)
    mean0 = a0 / (a0 + b0)
    ids = jnp.arange(cfg.num_grasps, dtype=jnp.int32)
    others = cand & (ids != choice[..., None])
    other_best = jnp.max(jnp.where(others, mean0, -jnp.inf), axis=-1)
    c = jnp.maximum(choice, 0)[..., None]
    alpha = jnp.take_along_axis(a0, c, axis=-1)[..., 0]
    beta = jnp.take_along_axis(b0, c, axis=-1)[..., 0]
    return FixedState(choice, alpha, beta, jnp.zeros(choice.shape, bool), other_best)


def select(st: FixedState, ctx: Ctx, cfg: Config, s, key):
    g = jnp.maximum(gather_at(st.choice, s), 0)
    return g, g, None


def update(st: FixedState, ctx: Ctx, cfg: Config, s, grasp, slot, reward, live):
    bi = jnp.arange(s.shape[0])
    was = st.attempted[bi, s]
    st = st._replace(
        alpha=st.alpha.at[bi, s].add((live & reward).astype(jnp.float32)),
        beta=st.beta.at[bi, s].add((live & ~reward).astype(jnp.float32)),
        attempted=st.attempted.at[bi, s].set(was | live),
    )
    return st, live & ~was


def recommend(st: FixedState, ctx: Ctx, cfg: Config, s):
    return gather_at(st.choice, s)


def recommend_init(st: FixedState, ctx: Ctx, cfg: Config):
    return st.choice


def estimates(st: FixedState, ctx: Ctx, cfg: Config):
    mean = st.alpha / (st.alpha + st.beta)
    has = st.choice >= 0
    best = jnp.where(has, jnp.maximum(mean, st.other_best), 0.0)
    tried = jnp.where(has & st.attempted, mean, 0.0)
    return best, tried


def candidates_dexnet(st: FixedState, ctx: Ctx, cfg: Config):
    return ctx.tables.valid[ctx.ot]


def candidates_top(st: FixedState, ctx: Ctx, cfg: Config):
    t = ctx.tables
    nv = t.n_valid[ctx.ot]
    rank = jnp.argsort(t.order[ctx.ot], axis=-1)  # rank of each grasp in the q order
    return (rank < cfg.top) & (rank < nv[..., None])


# The functions a method built on this state shares (besides ``init``).
_SHARED = (select, update, recommend, recommend_init, estimates)
FUNCTIONS = {f.__name__: f for f in _SHARED}
# What the constant rows share besides their functions: they do not learn; on
# their cards, a step touches one grasp and the benchmark charges them the rate of
# TQL (the same per-step work: one lookup, one update).
CONSTANT_ROW = dict(FUNCTIONS, learns=False)
CONSTANT_ROW_CARD = dict(cost=lambda cfg: 1.0, bench_proxy="tql")
