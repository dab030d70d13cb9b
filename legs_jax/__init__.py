"""legs_jax: exploratory grasping with LEGS and its baselines as batched JAX programs.

The names below are imported lazily, so that ``legs_jax.problem`` (used by the
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
    "run",
    "save",
    "stack",
]

_WHERE = {
    "ConfigError": "legs_jax.errors",
    "Method": "legs_jax.methods.base",
    "RunResult": "legs_jax.engine",
    "run": "legs_jax.engine",
    "Problem": "legs_jax.problem",
    "ProblemBatch": "legs_jax.problem",
    "load": "legs_jax.problem",
    "save": "legs_jax.problem",
    "stack": "legs_jax.problem",
    "make_problem": "legs_jax.synthetic",
}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'legs_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
