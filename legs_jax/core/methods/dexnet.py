"""Dex-Net: the grasp of highest prior q in each pose, no exploration.

A constant row: its gap never changes. It still runs in the environment, and its
Beta posterior of all K grasps (learning only from the fixed grasp) serves the
Dirichlet check.
"""

from legs_jax.core import reference as ref
from legs_jax.core.methods import _beta_twin as twin
from legs_jax.core.methods import _fixed
from legs_jax.core.methods.base import Card, Method

METHOD = Method(
    name="dexnet",
    description="Dex-Net: argmax prior, no exploration (constant gap)",
    **_fixed.CONSTANT_ROW,
    init=lambda ctx, cfg: _fixed.init(ctx, cfg, choose=_fixed.prior_choice),
    candidates=_fixed.candidates_dexnet,
    card=Card(
        **_fixed.CONSTANT_ROW_CARD,
        prior_only="greedy",
        label="Dex-Net (prior only)",
        short_label="Dex-Net*",
        style=dict(color="#7f7f7f", ls="--", lw=1.6),
        reference=lambda problem, trial, hp: twin.Fixed(
            problem, trial, hp, ref.prior_choice(problem, trial)
        ),
    ),
)
