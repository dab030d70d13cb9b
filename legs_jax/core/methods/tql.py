"""Tabular Q-learning: ε-greedy over all K grasps (ε: uniform over the
valid grasps), one-step update Q ← Q + η (r − Q), Q₀ = q."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from legs_jax.core import reference as ref
from legs_jax.core.methods.base import (
    UNIT,
    Card,
    Config,
    Ctx,
    Method,
    argmax_first,
    best_estimates,
    gather_at,
    updated_row,
)


class TQLHParams(NamedTuple):
    epsilon: float = 0.1  # exploration rate
    eta: float = 0.1  # learning rate


class TQLState(NamedTuple):
    Q: jax.Array  # [B, P, K] f32 action values
    attempted: jax.Array  # [B, P, K] bool tried at least once


def init(ctx: Ctx, cfg: Config) -> TQLState:
    q = ctx.tables.q[ctx.ot]
    return TQLState(q, jnp.zeros(q.shape, bool))


def _greedy(Q_row, valid_row):
    best = argmax_first(jnp.where(valid_row, Q_row, -jnp.inf))
    return jnp.where(jnp.any(valid_row, axis=-1), best, -1)


def select(st: TQLState, ctx: Ctx, cfg: Config, s, key):
    u = jax.vmap(lambda k: jax.random.uniform(k, (2,)))(key)  # [B, 2]
    valid = ctx.tables.valid[ctx.ot, s]  # [B, K]
    Q_row = gather_at(st.Q, s)
    greedy = jnp.maximum(_greedy(Q_row, valid), 0)
    nv = ctx.tables.n_valid[ctx.ot, s]
    j = jnp.clip(jnp.floor(u[:, 1] * nv).astype(jnp.int32), 0, jnp.maximum(nv - 1, 0))
    explore = ctx.tables.order[ctx.ot, s, j]  # uniform over the valid grasps
    g = jnp.where(u[:, 0] < ctx.hp.epsilon, explore, greedy)
    return g, g, (Q_row, valid)


def update(st: TQLState, ctx: Ctx, cfg: Config, s, grasp, slot, reward, live):
    bi = jnp.arange(s.shape[0])
    was = st.attempted[bi, s, slot]
    q = st.Q[bi, s, slot]
    dq = jnp.where(live, ctx.hp.eta * (reward.astype(jnp.float32) - q), 0.0)
    st = TQLState(
        Q=st.Q.at[bi, s, slot].add(dq),
        attempted=st.attempted.at[bi, s, slot].set(was | live),
    )
    return st, live & ~was


def recommend(st: TQLState, ctx: Ctx, cfg: Config, s):
    return _greedy(gather_at(st.Q, s), ctx.tables.valid[ctx.ot, s])


def recommend_updated(rows, ctx: Ctx, cfg: Config, s, slot, reward, live):
    Q_row, valid = rows
    q = jnp.take_along_axis(Q_row, slot[:, None], axis=1)[:, 0]
    dq = jnp.where(live, ctx.hp.eta * (reward.astype(jnp.float32) - q), 0.0)
    return _greedy(updated_row(Q_row, slot, dq), valid)


def recommend_init(st: TQLState, ctx: Ctx, cfg: Config):
    return _greedy(st.Q, ctx.tables.valid[ctx.ot])


def estimates(st: TQLState, ctx: Ctx, cfg: Config):
    return best_estimates(st.Q, ctx.tables.valid[ctx.ot], st.attempted)


def candidates(st: TQLState, ctx: Ctx, cfg: Config):
    return ctx.tables.valid[ctx.ot]


class Reference(ref.ReferenceMethod):
    """Tabular one-step Q-learning, ε-greedy: Q ← Q + η (r − Q), Q₀ = q."""

    def __init__(self, problem, trial, hp):
        super().__init__(problem, trial, hp)
        self.Q = self.q.copy()  # [P, K]

    def select(self, s: int, rng: np.random.Generator) -> int:
        if rng.random() < self.hp["epsilon"]:
            idx = np.flatnonzero(self.valid[s])  # explore: uniform over valid
            return int(idx[rng.integers(idx.size)])
        return ref.masked_argmax(self.Q[s], self.cand[s])

    def update(self, s: int, a: int, r: bool) -> None:
        super().update(s, a, r)
        self.Q[s, a] += self.hp["eta"] * (float(r) - self.Q[s, a])

    def _score(self) -> np.ndarray:
        return self.Q

    def _recommend_pose(self, s: int) -> int:
        return ref.masked_argmax(self.Q[s], self.cand[s])


METHOD = Method(
    name="tql",
    description="Tabular Q-learning, ε-greedy over all K grasps",
    init=init,
    select=select,
    update=update,
    recommend=recommend,
    recommend_updated=recommend_updated,
    recommend_init=recommend_init,
    estimates=estimates,
    candidates=candidates,
    hparams=TQLHParams,
    ranges={"epsilon": UNIT, "eta": UNIT},
    check=None,
    card=Card(
        bench=True,
        label="TQL",
        short_label="TQL",
        style=dict(color="#9467bd", ls="-", lw=1.6),
        cost=lambda cfg: cfg.num_grasps / 8.0,  # no sampling: a masked argmax
        dense=True,
        reference=Reference,
    ),
)
