"""The registry of exploration methods (SPEC §4).

Each method lives in its own module that defines ``METHOD``, a
:class:`legs_jax.methods.base.Method`; adding a method is adding one module and
its name to ``_MODULES`` (or calling :func:`register`).
"""

from __future__ import annotations

import importlib

from legs_jax.methods.base import Method

__all__ = ["Method", "get", "names", "register"]

# Registry order is the order of SPEC §4's table.
_MODULES = (
    "dexnet",
    "k100_ub",
    "borges_100",
    "borges_2000",
    "legs_no_as",
    "legs",
    "tql",
)
_REGISTRY: dict[str, Method] = {}


def register(method: Method) -> Method:
    """Add ``method`` under ``method.name`` (replacing one of the same name)."""
    _REGISTRY[method.name] = method
    return method


def _load() -> None:
    for mod in _MODULES:
        if mod not in _REGISTRY:
            register(importlib.import_module(f"legs_jax.methods.{mod}").METHOD)


def get(name: str) -> Method:
    """The registered method ``name``; KeyError if there is none."""
    _load()
    return _REGISTRY[name]


def names() -> tuple[str, ...]:
    """Names of the registered methods."""
    _load()
    return tuple(_REGISTRY)
