"""BORGES (K=100): Thompson sampling over the fixed top-100 grasps by q."""

from legs_jax.core.methods import _beta_twin as twin
from legs_jax.core.methods import _slots
from legs_jax.core.methods.base import TOP_FIXED, Card, Method

METHOD = Method(
    name="borges_100",
    description="BORGES (K=100): Thompson sampling over the top-100 by prior",
    **_slots.FUNCTIONS,
    init=lambda ctx, cfg: _slots.init(ctx, cfg, cfg.top, refill=False),
    card=Card(
        bench_proxy="legs",
        label="BORGES (K_s=100)",
        short_label="BORGES-100",
        style=dict(color="#ff7f0e", ls="-", lw=1.6),
        cost=lambda cfg: float(cfg.top),
        reference=lambda problem, trial, hp: twin.Borges(
            problem, trial, hp, top=TOP_FIXED
        ),
    ),
)
