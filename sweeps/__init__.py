"""The paper's experiments, declared as data (SPEC §7).

Each module is a handful of constants: ``NAME``, ``DESCRIPTION``, ``OBJECTS`` (set
or object names), ``ARMS`` (method, variant label, hyperparameters; a sequence
value is a grid that runs as one batch axis), ``TRIALS``, ``ROLLOUTS``,
``HORIZON``, ``RECORD_EVERY``, ``CHECK_EVERY``, ``CHECK_METHODS``,
``ACTIVE_SET_METHODS`` and ``SMOKE_OBJECTS``. ``python -m legs_jax.sweep`` runs them.
"""

import importlib
from types import ModuleType

__all__ = ["EXPERIMENTS", "get"]

EXPERIMENTS = ("main", "case_study", "early_stopping", "prior_strength", "confidence")


def get(name: str) -> ModuleType:
    """The module declaring experiment ``name``."""
    if name not in EXPERIMENTS:
        raise KeyError(name)
    return importlib.import_module(f"sweeps.{name}")
