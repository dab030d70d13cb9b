"""What the ``prior_strength`` experiment makes: the appendix table of the final gap
against the prior strength s, and its lines in the report (which also open the
report's appendix)."""

from __future__ import annotations

from collections.abc import Mapping

from legs_jax.report.document import Appendix, appendix_section
from legs_jax.report.figures import appendix_step

from .sweep import ARMS

# The appendix's table, LEGS on the bar clamp: s -> (mean, SE); delta = 0.07.
SPEC = Appendix(
    experiment="prior_strength",
    method=ARMS[0][0],  # the one method of the sweep
    param="s",
    name="prior strength s",
    caption="Sensitivity to prior strength s",
    other="delta",
    paper_fixed=0.07,
    paper={
        0.0: (0.285, 0.055),
        1.0: (0.125, 0.036),
        2.0: (0.128, 0.038),
        3.0: (0.171, 0.041),
        4.0: (0.148, 0.036),
        5.0: (0.187, 0.042),
    },
)


STEPS = (("appendix: prior strength", appendix_step(SPEC)),)


def _section(ctx: Mapping) -> list[str]:
    return [
        "## Appendix: prior strength s and confidence δ on the bar clamp",
        "",
        *appendix_section(ctx, SPEC),
    ]


SECTIONS = ((50, _section),)
