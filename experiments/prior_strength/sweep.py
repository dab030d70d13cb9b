"""Appendix, "Sensitivity to prior strength": LEGS on the bar clamp.

s in {0, 1, 2, 3, 4, 5} with delta = 0.07 (the appendix's setting); the grid runs
as one batch axis. Paper: s = 1 is best (0.125 +- 0.036).
"""

NAME = "prior_strength"
DESCRIPTION = "Appendix: LEGS on bar_clamp, s in 0..5, delta = 0.07"
ORDER = 4  # place in --all, the figures and the report

OBJECTS = ("bar_clamp",)

ARMS = (("legs", "", {"s": (0.0, 1.0, 2.0, 3.0, 4.0, 5.0), "delta": 0.07}),)

SMOKE_OBJECTS = ("bar_clamp",)
