"""BORGES (K=2000): Thompson sampling over every grasp of the pose."""

from legs_jax.core.methods import _beta_twin as twin
from legs_jax.core.methods import _dense
from legs_jax.core.methods.base import Card, Method

METHOD = Method(
    name="borges_2000",
    description="BORGES (K=2000): Thompson sampling over all K grasps",
    **_dense.FUNCTIONS,
    init=lambda ctx, cfg: _dense.init(ctx, cfg, removable=False),
    card=Card(
        bench=True,
        label="BORGES (K_s=2000)",
        short_label="BORGES-2000",
        style=dict(color="#2ca02c", ls="-", lw=1.6),
        dense=True,
        reference=lambda problem, trial, hp: twin.Borges(problem, trial, hp, top=None),
    ),
)
