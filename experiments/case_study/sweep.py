"""Fig. 3: learning curves of every method on four objects ("case study").

Climbing hold and C3 (where LEGS converges faster) and F6 and turbine housing (where
it does not beat every baseline). Besides the learning curves, the active set of
LEGS (trial 0, rollout 0 of each object) is recorded at every check, and the
ground-truth robustness of trial 0's reservoir is saved for the histogram.
"""

from experiments.main import sweep as main

NAME = "case_study"
DESCRIPTION = "Fig. 3: learning curves, robustness histograms, LEGS active sets"
ORDER = 2  # place in --all, the figures and the report

OBJECTS = ("climbing_hold", "C3", "F6", "turbine_housing")

# Every method of Table I in its default configuration.
ARMS = tuple(arm for arm in main.ARMS if arm[1] == "")

CHECK_METHODS = ("legs",)
ACTIVE_SET_METHODS = ("legs",)

SMOKE_OBJECTS = ("climbing_hold", "C3")
