"""The paper's experiments, one folder each: ``experiments/<name>/``.

``sweep.py`` declares the experiment as data, a handful of constants: ``NAME``,
``DESCRIPTION``, ``ORDER`` (its place in ``--all``, the figures and the report),
``OBJECTS`` (set or object names), ``ARMS`` (method, variant label,
hyperparameters; a sequence value is a grid that runs as one batch axis),
``SMOKE_OBJECTS`` and, where they differ from :data:`DEFAULTS`, ``TRIALS``,
``ROLLOUTS``, ``HORIZON``, ``RECORD_EVERY``, ``CHECK_EVERY``, ``CHECK_METHODS``
(methods whose Dirichlet checks go to checks.parquet) and ``ACTIVE_SET_METHODS``
(methods whose active sets go to active_set.parquet, trial 0, rollout 0), and
``PRIOR`` where the problems carry another prior than the default (``precompute
--prior``); any other uppercase constant stays available on the declaration that
:func:`get` returns.
``python -m legs_jax.sweep`` runs them.

``analysis.py`` holds what the experiment makes from its results: ``STEPS``
(label, function of a :class:`legs_jax.report.figures.Run`) that write its tables and
figures, and ``SECTIONS`` (position, function of the report's context) that write
its parts of ``REPORT.md``. A new experiment is a new folder; nothing else changes.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType, SimpleNamespace

from legs_jax.report.figures import Experiment

__all__ = [
    "DEFAULTS",
    "EXPERIMENTS",
    "analysis",
    "declared_methods",
    "for_report",
    "get",
    "names",
]

# The sizes (T x R = 10 x 10 runs of H = 3000 steps per object, the gap
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

_HERE = Path(__file__).resolve().parent


def _declaration(name: str) -> ModuleType:
    return importlib.import_module(f"{__name__}.{name}.sweep")


def names() -> tuple[str, ...]:
    """The experiments: every folder here with a ``sweep.py``, by ``ORDER`` (then
    by name)."""
    found = sorted(
        p.parent.name
        for p in _HERE.glob("*/sweep.py")
        if (p.parent / "__init__.py").is_file()
    )
    rank = {n: getattr(_declaration(n), "ORDER", float("inf")) for n in found}
    return tuple(sorted(found, key=lambda n: (rank[n], n)))


EXPERIMENTS = names()


def get(name: str) -> SimpleNamespace:
    """The declaration of experiment ``name``: its ``sweep.py`` constants over
    :data:`DEFAULTS`."""
    if name not in EXPERIMENTS:
        raise KeyError(name)
    mod = _declaration(name)
    own = {k: v for k, v in vars(mod).items() if k.isupper()}
    return SimpleNamespace(**{**DEFAULTS, **own})


def declared_methods() -> set[str]:
    """The methods some experiment declares an arm of (the others, such as a
    user's own, run with their defaults when asked for by name)."""
    return {m for n in EXPERIMENTS for m, _, _ in get(n).ARMS}


def analysis(name: str) -> ModuleType | None:
    """The ``analysis.py`` of experiment ``name``, or None when it has none."""
    if name not in EXPERIMENTS:
        raise KeyError(name)
    if not (_HERE / name / "analysis.py").is_file():
        return None
    return importlib.import_module(f"{__name__}.{name}.analysis")


def for_report() -> list:
    """Every experiment as the report takes it
    (:class:`legs_jax.report.figures.Experiment`: name, declared arms, the steps
    and sections of its ``analysis.py``), in ``--all``'s order."""
    out = []
    for name in EXPERIMENTS:
        mod = analysis(name)
        out.append(
            Experiment(
                name=name,
                arms=tuple(get(name).ARMS),
                steps=tuple(getattr(mod, "STEPS", ())),
                sections=tuple(getattr(mod, "SECTIONS", ())),
            )
        )
    return out
