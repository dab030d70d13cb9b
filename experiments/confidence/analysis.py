"""What the ``confidence`` experiment makes: the appendix table of the final gap
against the confidence parameter δ, and its lines in the report's appendix."""

from __future__ import annotations

from collections.abc import Mapping

from legs_jax.report.document import Appendix, appendix_section
from legs_jax.report.figures import appendix_step

from .sweep import ARMS

# The appendix's table, LEGS on the bar clamp: delta -> (mean, SE); s = 1.
SPEC = Appendix(
    experiment="confidence",
    method=ARMS[0][0],  # the one method of the sweep
    param="delta",
    name="confidence δ",
    caption="Sensitivity to the confidence parameter δ",
    other="s",
    paper_fixed=1.0,
    paper={
        0.01: (0.129, 0.040),
        0.05: (0.103, 0.031),
        0.10: (0.156, 0.043),
        0.15: (0.148, 0.041),
        0.20: (0.214, 0.051),
        0.25: (0.174, 0.044),
    },
)


STEPS = (("appendix: confidence", appendix_step(SPEC)),)


def _section(ctx: Mapping) -> list[str]:
    return appendix_section(ctx, SPEC)


SECTIONS = ((51, _section),)
