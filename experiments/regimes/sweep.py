"""When does LEGS win? A map of regimes on generated problems.

The paper closes by asking how the prior's quality and the distribution of grasp
success probabilities affect LEGS's convergence. This experiment answers it on
problems whose properties are set one at a time (``legs_jax.families``, seeded:
every problem is generated from seed 0, so two problems differ only in the
property that names them and share their draws):

- the main map: the shape of the p distribution of a pose (``hump`` like our
  reservoirs, ``skewed``, ``low``, ``bimodal`` like the paper's Fig. 3; 1 % of
  excellent grasps in each) x the prior's C-index (0.5, 0.7, 0.85, 0.95), with a
  calibrated prior, 8 poses of 4 effective poses;
- side axes around the map: the prior's calibration (optimistic, pessimistic),
  the share of excellent grasps (0.25 %, 4 %), the concentration of the landing
  probabilities (1.5 and 8 effective poses), and the horizon H (read from the gap
  curves at 500, 1000 and 3000 steps).

Methods: every registered method with its defaults, and LEGS with the settings
the issue's measurements point at: a global threshold γ that fires (0.5, 0.8, a
grid on one batch axis), a smaller active set (k = 20) and more frequent pruning
(n = 20). T x R = 5 x 10 runs of H = 3000 steps per problem and arm (sized to
run in under 20 minutes on a 2-core CPU: BENCHMARKS.md, "regimes").
"""

from experiments.main import sweep as _main

NAME = "regimes"
DESCRIPTION = "When does LEGS win: generated problems, prior x p-distribution map"
ORDER = 7  # place in --all, the figures and the report

SHAPES = ("hump", "skewed", "low", "bimodal")
AUCS = (0.5, 0.7, 0.85, 0.95)
# The reference cell the side axes move away from.
REFERENCE = dict(shape="hump", auc=0.85)
BASE = dict(
    seed=0,
    excellent=0.01,
    calibration="calibrated",
    num_poses=8,
    effective_poses=4.0,
    num_grasps=2000,
    num_trials=5,
)


def _family(shape: str, auc: float, **change) -> tuple[str, dict]:
    kw = {**BASE, "shape": shape, "auc": auc, **change}
    name = f"{shape}-auc{auc:.2f}"
    for k, v in change.items():
        name += f"-{k}{v}" if k != "calibration" else f"-{v}"
    return name, kw


# (problem name, keyword arguments of legs_jax.families.make_problem).
GENERATED = (
    *(_family(s, a) for s in SHAPES for a in AUCS),
    *(
        _family(s, 0.85, calibration=c)
        for s in ("hump", "bimodal")
        for c in ("optimistic", "pessimistic")
    ),
    _family("hump", 0.85, excellent=0.0025),
    _family("hump", 0.85, excellent=0.04),
    _family("bimodal", 0.85, excellent=0.04),
    _family("hump", 0.85, effective_poses=1.5),
    _family("hump", 0.85, effective_poses=8.0),
    _family("bimodal", 0.95, effective_poses=1.5),
)
# The generated problems are the objects (bench.projection counts them).
OBJECTS = tuple(n for n, _ in GENERATED)

ARMS = (
    ("dexnet", "", {}),
    ("k100_ub", "", {}),
    ("borges_100", "", {}),
    ("borges_2000", "", {}),
    ("legs_no_as", "", {}),
    ("legs", "", {}),
    ("tql", "", {}),
    ("bayes_ucb_100", "", {}),
    ("bayes_ucb_2000", "", {}),
    # LEGS with the settings the measurements point at (the pruning never fires).
    ("legs", "gamma", {"gamma": (0.5, 0.8)}),
    ("legs", "k20", {"k": 20}),
    ("legs", "n20", {"n": 20}),
    # Ours: Bayes-UCB (K=100) with each grasp's prior fed by its pose's outcomes.
    ("pooled_ucb", "", {}),
)

# Our own method (the report sets it against every other arm): main's declaration.
OURS = _main.OURS

TRIALS = 5
ROLLOUTS = 10
# The horizons the map reads from the gap curves.
HORIZONS = (500, 1000, 3000)

SMOKE_OBJECTS = OBJECTS[:2]
