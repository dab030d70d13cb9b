"""LEGS whose pruning runs on each pose's own clock: pose s is pruned after every
n-th grasp attempt made in pose s, where LEGS prunes at every n-th step of the
rollout whatever the pose. A method of one file (the schedule is its
``prune_due``); the engine runs it unchanged (``tests/test_own_schedule.py``)."""

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from legs_jax.core.methods import _slots, legs
from legs_jax.core.methods.base import Card, gather_at


class State(NamedTuple):
    inner: _slots.SlotState  # LEGS's slots
    count: jax.Array  # [B, P] i32 grasp attempts made in each pose


def init(ctx, cfg):
    inner = _slots.init(ctx, cfg, cfg.k, refill=True)
    return State(inner, jnp.zeros(inner.next.shape, jnp.int32))


def update(st, ctx, cfg, s, grasp, slot, reward, live):
    inner, new = _slots.update(st.inner, ctx, cfg, s, grasp, slot, reward, live)
    bi = jnp.arange(s.shape[0])
    return State(inner, st.count.at[bi, s].add(live.astype(jnp.int32))), new


def prune_due(st, ctx, cfg, s, t):
    """After the update: pose s has just had its n-th, 2n-th, ... attempt."""
    count = gather_at(st.count, s)
    return (count > 0) & (count % cfg.n == 0)


def prune(st, ctx, cfg, s, live):
    inner, removed = _slots.prune_refill(st.inner, ctx, cfg, s, live)
    return st._replace(inner=inner), removed


def _inner(f):
    """``f`` of the slots, applied to the LEGS part of the state."""
    return lambda st, *args: f(st.inner, *args)


METHOD = dataclasses.replace(
    legs.METHOD,
    name="legs_per_pose",
    description="LEGS pruning every n attempts of the pose itself",
    init=init,
    update=update,
    prune=prune,
    prune_due=prune_due,
    card=Card(
        label="LEGS (pruned by the pose's attempts)",
        short_label="LEGS-pose",
        cost=legs.METHOD.card.cost,
    ),
    **{
        name: _inner(getattr(_slots, name))
        for name in (
            "select",
            "recommend",
            "recommend_init",
            "estimates",
            "counts",
            "candidates",
            "active_set",
        )
    },
)
