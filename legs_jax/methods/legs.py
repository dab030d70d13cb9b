"""LEGS (Algorithm 1): Thompson sampling over an active set of k grasps per pose,
pruned every n steps by the LEGS rule and refilled from the reservoir in descending
q (SPEC §4).

The active set of every pose is built at step 0 (it depends on nothing learned, so
this equals building it on the first visit). :func:`prune` is the pruning step of
one pose as a pure function of the state; :func:`legs_jax.methods.base.prune_mask`
is the removal set alone.
"""

from legs_jax.methods import _slots
from legs_jax.methods.base import Method, prune_mask

__all__ = ["METHOD", "SlotState", "prune", "prune_mask"]

SlotState = _slots.SlotState
prune = _slots.prune_refill

METHOD = Method(
    name="legs",
    description="LEGS: active set of k grasps, pruned and refilled",
    init=lambda ctx, cfg: _slots.init(ctx, cfg, cfg.k, refill=True),
    select=_slots.select,
    update=_slots.update,
    recommend=_slots.recommend,
    recommend_updated=_slots.recommend_updated,
    recommend_init=_slots.recommend_init,
    estimates=_slots.estimates,
    candidates=_slots.candidates,
    prune=_slots.prune_refill,
    active_set=_slots.active_set,
)
