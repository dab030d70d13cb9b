"""Table I: every method on every object (SPEC §7, "main").

All seven methods of SPEC §4 with their default hyperparameters, plus BORGES
(K=2000) with the original BORGES code's prior (``prior_offset = 0, s = 5``, SPEC
§3) as the extra variant ``orig_prior``. T x R = 10 x 10 runs of H = 3000 steps per
object. Dirichlet checks are recorded for LEGS only (they cost more than the cheap
methods' own steps and only LEGS's are analysed).
"""

NAME = "main"
DESCRIPTION = "Table I: all methods, all objects, final optimality gap"

# Object set names (``dexnet_adv``, ``egad_eval``) or object names.
OBJECTS = ("dexnet_adv", "egad_eval")

# (method, variant label, hyperparameters). "" is the default configuration.
ARMS = (
    ("dexnet", "", {}),
    ("k100_ub", "", {}),
    ("borges_100", "", {}),
    ("borges_2000", "", {}),
    ("borges_2000", "orig_prior", {"prior_offset": 0.0, "s": 5.0}),
    ("legs_no_as", "", {}),
    ("legs", "", {}),
    ("tql", "", {}),
)

TRIALS = 10
ROLLOUTS = 10
HORIZON = 3000
RECORD_EVERY = 10
CHECK_EVERY = 100

# Methods whose Dirichlet checks go to checks.parquet.
CHECK_METHODS = ("legs",)
# Methods whose active sets go to active_set.parquet (trial 0, rollout 0).
ACTIVE_SET_METHODS = ()

# Objects used by --smoke (synthetic problems carrying these names).
SMOKE_OBJECTS = ("bar_clamp", "A0")
