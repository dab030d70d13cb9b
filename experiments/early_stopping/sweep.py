"""Section 5.4 and Fig. 4: the Dirichlet early-stopping bound.

LEGS on the Dex-Net adversarial set, checked every 100 steps up to H = 3000 with
delta_stop = 0.05 and M = 3000 Dirichlet samples. Both lower bounds are recorded:
p_lower (the paper's formula, p-hat* over all candidates) and p_lower_attempted
(p-hat* over attempted grasps only). Accuracy, tightness and the rho_min
sensitivity are computed from checks.parquet.
"""

NAME = "early_stopping"
DESCRIPTION = "Sec. 5.4 / Fig. 4: accuracy and tightness of the stopping bound"
ORDER = 3  # place in --all, the figures and the report

OBJECTS = ("dexnet_adv",)

ARMS = (("legs", "", {}),)

CHECK_METHODS = ("legs",)

# Stopping thresholds of the sensitivity analysis (Fig. 4): 0.05, 0.10, ..., 0.95.
RHO_MIN = tuple(round(0.05 * i, 2) for i in range(1, 20))

SMOKE_OBJECTS = ("bar_clamp", "pawn")
