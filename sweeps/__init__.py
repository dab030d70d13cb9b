"""The paper's experiments, declared as data (SPEC §7).

Each module is a handful of constants: ``NAME``, ``DESCRIPTION``, ``OBJECTS`` (set
or object names), ``ARMS`` (method, variant label, hyperparameters; a sequence
value is a grid that runs as one batch axis), ``SMOKE_OBJECTS`` and, where they
differ from :data:`DEFAULTS`, ``TRIALS``, ``ROLLOUTS``, ``HORIZON``,
``RECORD_EVERY``, ``CHECK_EVERY``, ``CHECK_METHODS`` (methods whose Dirichlet
checks go to checks.parquet) and ``ACTIVE_SET_METHODS`` (methods whose active
sets go to active_set.parquet, trial 0, rollout 0), and ``PRIOR`` where the
problems carry another prior than the default (``precompute --prior``).
``python -m legs_jax.sweep`` runs them.
"""

import importlib
from types import SimpleNamespace

__all__ = ["DEFAULTS", "EXPERIMENTS", "get"]

EXPERIMENTS = (
    "main",
    "case_study",
    "early_stopping",
    "prior_strength",
    "confidence",
    "prior_synthetic",
)
# The sizes of SPEC §7 (T x R = 10 x 10 runs of H = 3000 steps per object, the gap
# every 10 steps, a check every 100) and nothing recorded beyond the runs.
DEFAULTS = dict(
    TRIALS=10,
    ROLLOUTS=10,
    HORIZON=3000,
    RECORD_EVERY=10,
    CHECK_EVERY=100,
    CHECK_METHODS=(),
    ACTIVE_SET_METHODS=(),
)


def get(name: str) -> SimpleNamespace:
    """The declaration of experiment ``name``: its module's constants over
    :data:`DEFAULTS`."""
    if name not in EXPERIMENTS:
        raise KeyError(name)
    mod = importlib.import_module(f"sweeps.{name}")
    own = {k: v for k, v in vars(mod).items() if k.isupper()}
    return SimpleNamespace(**{**DEFAULTS, **own})
