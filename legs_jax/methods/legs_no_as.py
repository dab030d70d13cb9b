"""LEGS(-AS): Thompson sampling over all K grasps, pruned by the LEGS rule of SPEC §4
every n steps (the pose just grasped), with no refill."""

from legs_jax.methods import _dense
from legs_jax.methods.base import Method

METHOD = Method(
    name="legs_no_as",
    description="LEGS(-AS): all K grasps, LEGS pruning, no active set",
    init=lambda ctx, cfg: _dense.init(ctx, cfg, removable=True),
    select=_dense.select,
    update=_dense.update,
    recommend=_dense.recommend,
    recommend_updated=_dense.recommend_updated,
    recommend_init=_dense.recommend_init,
    estimates=_dense.estimates,
    candidates=_dense.candidates,
    prune=_dense.prune,
)
