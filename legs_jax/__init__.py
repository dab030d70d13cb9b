"""legs_jax: exploratory grasping with LEGS and its baselines as batched JAX programs.

The names below are imported lazily, so that ``legs_jax.core.problem`` (used by the
precompute step) does not pull in JAX.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "ConfigError",
    "Method",
    "Problem",
    "ProblemBatch",
    "RunResult",
    "load",
    "make_problem",
    "methods",
    "run",
    "save",
    "stack",
]

_WHERE = {
    "ConfigError": "legs_jax.errors",
    "Method": "legs_jax.core.methods.base",
    "RunResult": "legs_jax.runtime.rollouts",
    "run": "legs_jax.runtime.rollouts",
    "Problem": "legs_jax.core.problem",
    "ProblemBatch": "legs_jax.core.problem",
    "load": "legs_jax.core.problem",
    "save": "legs_jax.core.problem",
    "stack": "legs_jax.core.problem",
    "make_problem": "legs_jax.synthetic",
}


# Subpackages reachable from the top: ``from legs_jax import methods`` is the
# method registry, :mod:`legs_jax.core.methods`.
_MODULES = {"methods": "legs_jax.core.methods"}


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        return importlib.import_module(_MODULES[name])
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'legs_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
