"""BORGES (K=100): Thompson sampling over the fixed top-100 grasps by q (SPEC §4)."""

from legs_jax.methods import _slots
from legs_jax.methods.base import Method

METHOD = Method(
    name="borges_100",
    description="BORGES (K=100): Thompson sampling over the top-100 by prior",
    init=lambda ctx, cfg: _slots.init(ctx, cfg, cfg.top, refill=False),
    select=_slots.select,
    update=_slots.update,
    recommend=_slots.recommend,
    recommend_updated=_slots.recommend_updated,
    recommend_init=_slots.recommend_init,
    estimates=_slots.estimates,
    candidates=_slots.candidates,
)
