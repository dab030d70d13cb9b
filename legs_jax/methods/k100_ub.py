"""The K100 upper bound: in each pose, the grasp of highest ground-truth p among the
top-100 by prior q (SPEC §4). An oracle row, not a method; its gap is constant and
bounds what BORGES (K=100) can reach.
"""

from legs_jax.methods import _fixed
from legs_jax.methods.base import Method

METHOD = Method(
    name="k100_ub",
    description="K100 upper bound: best true grasp of the top-100 by prior (oracle)",
    init=lambda ctx, cfg: _fixed.init(ctx, cfg, which="k100_ub"),
    select=_fixed.select,
    update=_fixed.update,
    recommend=_fixed.recommend,
    recommend_init=_fixed.recommend_init,
    estimates=_fixed.estimates,
    candidates=_fixed.candidates_top,
    learns=False,
)
