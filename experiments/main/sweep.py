"""Table I: every method on every object ("main").

All seven methods with their default hyperparameters, plus BORGES
(K=2000) with the original BORGES code's prior (``prior_offset = 0, s = 5``) as
the extra variant ``orig_prior``, Bayes-UCB (K=100 and K=2000) as extra
rows, and our own method, Pooled Bayes-UCB. T x R = 10 x 10 runs of
H = 3000 steps per object. Dirichlet checks are recorded for LEGS only (they
cost more than the cheap methods' own steps and only LEGS's are analysed).
"""

NAME = "main"
DESCRIPTION = "Table I: all methods, all objects, final optimality gap"
ORDER = 1  # place in --all, the figures and the report

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
    # Extra rows, not the paper's: Bayes-UCB over the Beta posteriors.
    ("bayes_ucb_100", "", {}),
    ("bayes_ucb_2000", "", {}),
    # Ours: Bayes-UCB (K=100) with each grasp's prior fed by its pose's outcomes.
    ("pooled_ucb", "", {}),
)

# Dirichlet checks of LEGS only (experiments.DEFAULTS holds the rest).
CHECK_METHODS = ("legs",)

# Objects used by --smoke (synthetic problems carrying these names).
SMOKE_OBJECTS = ("bar_clamp", "A0")

# ------------------------------------------- how its arms are ordered and labelled
# Table I's column order in the paper; other methods in the results (extra rows
# such as Bayes-UCB, or a user's method) follow in registry order.
TABLE_ORDER = (
    "dexnet",
    "tql",
    "borges_100",
    "k100_ub",
    "borges_2000",
    "legs_no_as",
    "legs",
)
# The method the paper proposes: the subject of the win counts and the prose.
PROPOSED = "legs"
# Our own method: the report sets it against every other row but the oracle.
OURS = "pooled_ucb"
# Labels and figure styles of the variants (a method's own are in its declaration).
VARIANTS = {
    ("borges_2000", "orig_prior"): dict(
        label="BORGES (K_s=2000), original prior (s=5, offset 0)",
        short_label="BORGES-2000 (s=5, offset 0)",
        style=dict(color="#98df8a", ls="-.", lw=1.6),
    ),
}
