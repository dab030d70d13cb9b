"""Fig. 3: learning curves of every method on four objects (SPEC §7, "case study").

Climbing hold and C3 (where LEGS converges faster) and F6 and turbine housing (where
it does not beat every baseline). Besides the learning curves, the active set of
LEGS (trial 0, rollout 0 of each object) is recorded at every check, and the
ground-truth robustness of trial 0's reservoir is saved for the histogram.
"""

NAME = "case_study"
DESCRIPTION = "Fig. 3: learning curves, robustness histograms, LEGS active sets"

OBJECTS = ("climbing_hold", "C3", "F6", "turbine_housing")

ARMS = (
    ("dexnet", "", {}),
    ("k100_ub", "", {}),
    ("borges_100", "", {}),
    ("borges_2000", "", {}),
    ("legs_no_as", "", {}),
    ("legs", "", {}),
    ("tql", "", {}),
)

TRIALS = 10
ROLLOUTS = 10
HORIZON = 3000
RECORD_EVERY = 10
CHECK_EVERY = 100

CHECK_METHODS = ("legs",)
ACTIVE_SET_METHODS = ("legs",)

SMOKE_OBJECTS = ("climbing_hold", "C3")
