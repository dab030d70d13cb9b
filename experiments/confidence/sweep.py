"""Appendix, "Sensitivity to confidence interval parameter": LEGS on the bar clamp.

delta in {0.01, 0.05, 0.10, 0.15, 0.20, 0.25} with s = 1; the grid runs as one batch
axis. Paper: delta = 0.05 is best (0.103 +- 0.031).
"""

NAME = "confidence"
DESCRIPTION = "Appendix: LEGS on bar_clamp, delta in 0.01..0.25, s = 1"
ORDER = 5  # place in --all, the figures and the report

OBJECTS = ("bar_clamp",)

ARMS = (("legs", "", {"delta": (0.01, 0.05, 0.10, 0.15, 0.20, 0.25), "s": 1.0}),)

SMOKE_OBJECTS = ("bar_clamp",)
