"""The K100 upper bound: in each pose, the grasp of highest ground-truth p among the
top-100 by prior q. An oracle row, not a method; its gap is constant and
bounds what BORGES (K=100) can reach.
"""

from legs_jax.core import reference as ref
from legs_jax.core.methods import _beta_twin as twin
from legs_jax.core.methods import _fixed
from legs_jax.core.methods.base import TOP_FIXED, Card, Method

METHOD = Method(
    name="k100_ub",
    description="K100 upper bound: best true grasp of the top-100 by prior (oracle)",
    **_fixed.CONSTANT_ROW,
    init=lambda ctx, cfg: _fixed.init(ctx, cfg, choose=_fixed.top_truth_choice),
    candidates=_fixed.candidates_top,
    card=Card(
        **_fixed.CONSTANT_ROW_CARD,
        prior_only="top",
        label="K_s=100 upper bound",
        short_label="K100-UB",
        style=dict(color="#000000", ls=":", lw=1.6),
        oracle=True,
        reference=lambda problem, trial, hp: twin.Fixed(
            problem,
            trial,
            hp,
            ref.top_truth_choice(problem, trial, TOP_FIXED),
            top=TOP_FIXED,
        ),
    ),
)
