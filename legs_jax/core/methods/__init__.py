"""The registry of exploration methods: the one list of them.

Each method lives in its own module of this folder that defines ``METHOD``, a
:class:`legs_jax.core.methods.base.Method` declaring its algorithm (functions,
hyperparameters, pruning schedule) and its :class:`~legs_jax.core.methods.base.Card`
(labels, style, costs); a new module is found without being listed. Everything else
(the engine, the NumPy reference, the sweep, the benchmark, the analysis and the
figures) asks this registry. A method from outside
the package is named ``my_pkg.my_module:METHOD`` (:func:`resolve`) and passes the
same conformance checks as ours (:mod:`legs_jax.runtime.conformance`).
"""

from __future__ import annotations

import importlib
import math
import numbers
import pkgutil
from collections.abc import Mapping
from typing import Any

import numpy as np

from legs_jax.core.methods.base import Method, check_declaration
from legs_jax.errors import ConfigError

__all__ = [
    "DEFAULT",
    "Method",
    "builtin",
    "column_defaults",
    "get",
    "names",
    "parse_grid",
    "register",
    "resolve",
]

# The paper's methods, in the order' table; every other module of this
# folder that defines ``METHOD`` follows, by name (a new method is one new file).
_PAPER = (
    "dexnet",
    "k100_ub",
    "borges_100",
    "borges_2000",
    "legs_no_as",
    "legs",
    "tql",
)
# The method run where none is named (the online session, its CLI): the paper's.
DEFAULT = "legs"
_NOT_METHODS = ("base",)
_REGISTRY: dict[str, Method] = {}


def _modules() -> tuple[str, ...]:
    found = sorted(
        m.name
        for m in pkgutil.iter_modules(__path__)
        if not m.name.startswith("_") and m.name not in _NOT_METHODS
    )
    return _PAPER + tuple(m for m in found if m not in _PAPER)


_MODULES = _modules()


def register(method: Method) -> Method:
    """Add ``method`` under ``method.name`` (replacing one of the same name)."""
    if not isinstance(method, Method):
        raise ConfigError(
            f"a method must be a legs_jax.core.methods.base.Method, got "
            f"{type(method).__name__}"
        )
    _REGISTRY[method.name] = method
    return method


def _load() -> None:
    for mod in _MODULES:
        if mod not in _REGISTRY:
            register(importlib.import_module(f"legs_jax.core.methods.{mod}").METHOD)


def get(name: str) -> Method:
    """The registered method ``name``; KeyError if there is none."""
    _load()
    return _REGISTRY[name]


def names() -> tuple[str, ...]:
    """Names of the registered methods, the package's first."""
    _load()
    return tuple(_REGISTRY)


def resolve(spec: str | Method) -> Method:
    """A method from its registered name, from ``module.path:ATTRIBUTE`` (a
    method in the user's own module, imported and registered under its name), or
    a :class:`Method` itself. A method from outside the registry is checked first
    (:func:`legs_jax.core.methods.base.check_declaration`)."""
    if isinstance(spec, Method):
        return spec
    if not isinstance(spec, str):
        raise ConfigError(f"a method is a name or a Method, got {spec!r}")
    _load()
    if spec in _REGISTRY:
        return _REGISTRY[spec]
    if ":" not in spec:
        known = ", ".join(_REGISTRY)
        raise ConfigError(
            f"unknown method '{spec}' (known: {known}; or module.path:ATTRIBUTE for "
            "a method of your own)"
        )
    module, _, attr = spec.partition(":")
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        raise ConfigError(f"method '{spec}': cannot import {module} ({e})") from None
    method = getattr(mod, attr, None)
    if method is None:
        raise ConfigError(f"method '{spec}': {module} has no attribute {attr}")
    check_declaration(method, where=spec)
    known = _REGISTRY.get(method.name)
    if known is not None and known is not method:
        raise ConfigError(
            f"method '{spec}' is named '{method.name}', the name of another "
            "registered method; give it a name of its own"
        )
    return register(method)


def builtin(name: str) -> bool:
    """Whether ``name`` is one of this package's methods (not the user's)."""
    return name in _MODULES


def column_defaults() -> dict[str, float | int]:
    """The hyperparameter columns every result row carries, in their order, and
    the value each holds for a method that does not have that hyperparameter:
    every hyperparameter of this package's methods, those of :data:`DEFAULT`
    first, then the others in registry order, with the default of the first
    method declaring it. (A user's method adds its own columns to its rows.)"""
    _load()
    out: dict[str, float | int] = {}
    for name in (DEFAULT, *_MODULES):
        for hp, value in _REGISTRY[name].defaults().items():
            out.setdefault(hp, value)
    return out


def _is_real(x: Any) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def parse_grid(
    method: Method, hparams: Mapping[str, Any] | None, num_grasps: int | None = None
) -> tuple[int, dict[str, np.ndarray]]:
    """Validate hyperparameter overrides of ``method`` and broadcast them to a
    grid of G points: every value a number or a flat sequence, all sequences of
    one length G (a zipped grid, not a product). Returns G and every
    hyperparameter of the method as an array [G] (float64; int64 for integer
    ones). ``num_grasps`` K enables the checks that need it (k <= K). Raises
    :class:`ConfigError` with a one-line message."""
    hp: dict[str, Any] = method.defaults()
    if hparams is not None:
        if not isinstance(hparams, Mapping):
            raise ConfigError(
                f"hparams must be a mapping of name -> value, got {hparams!r}"
            )
        unknown = sorted(set(hparams) - set(hp), key=str)
        if unknown:
            raise ConfigError(
                f"unknown hyperparameter(s) {', '.join(map(str, unknown))} of "
                f"{method.name}; known: {', '.join(hp)}"
            )
        hp.update(hparams)
    G = 1
    values: dict[str, np.ndarray] = {}
    for name, v in hp.items():
        if isinstance(v, (str, bytes)):
            raise ConfigError(f"hyperparameter {name} must be a number, got {v!r}")
        arr = np.asarray(v, dtype=object)
        if arr.ndim > 1:
            raise ConfigError(
                f"hyperparameter {name} must be a number or a flat sequence, "
                f"got shape {arr.shape}"
            )
        if arr.ndim == 1:
            if arr.size == 0:
                raise ConfigError(f"hyperparameter {name} is an empty sequence")
            if G != 1 and arr.size != G:
                raise ConfigError(
                    f"hyperparameter sequences must have equal lengths (a zipped "
                    f"grid): {name} has {arr.size} values, others {G}"
                )
            G = arr.size
        values[name] = arr.reshape(-1)
    out: dict[str, np.ndarray] = {}
    for name, arr in values.items():
        rng = method.ranges.get(name)
        for x in arr:
            if not _is_real(x):
                raise ConfigError(f"hyperparameter {name} must be a number, got {x!r}")
            if not math.isfinite(float(x)):
                raise ConfigError(f"hyperparameter {name} must be finite, got {x!r}")
            if rng is not None and not rng.contains(float(x)):
                raise ConfigError(f"{name} must {rng.describe()}, got {x!r}")
        full = np.broadcast_to(arr, (G,))
        integer = rng is not None and rng.integer
        out[name] = full.astype(np.int64 if integer else np.float64)
    if method.check is not None:
        method.check(out, num_grasps)
    return G, out
