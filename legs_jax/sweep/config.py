"""What a sweep runs, as one typed value: :class:`SweepConfig`.

The command line (:mod:`legs_jax.sweep.cli`) and the Python entry
(:func:`legs_jax.sweep.run`) both build a :class:`SweepConfig` and check it with
:func:`validate`, which returns the normalised configuration (methods split at
commas, the grid as zipped value sequences, the experiments named) or raises a
:class:`~legs_jax.errors.ConfigError` with a one-line message. :func:`default_out`
says where its results go without an explicit folder.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import itertools
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import experiments
from legs_jax.errors import ConfigError
from precompute.mesh import _MESH_SUFFIXES  # what precompute --mesh reads

__all__ = [
    "RESULTS",
    "RUNS",
    "SweepConfig",
    "default_out",
    "own_configuration",
    "parse_grid",
    "validate",
]

# The folder of the paper's experiments at their declared configuration, and the
# one under which any other configuration gets a folder of its own.
RESULTS = "results"
RUNS = "runs"
_SLUG_MAX = 80


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """One sweep: what to run, at what size, where, on which devices.

    Every field has the command line's default; see ``python -m legs_jax.sweep
    --help`` for each (the field ``experiment`` is ``--experiment``, and so on).
    ``grid`` maps a hyperparameter to its values, e.g. ``{"delta": (0.01, 0.1),
    "s": (0, 1)}``: every combination runs (after :func:`validate`, the values
    are zipped sequences, one entry per grid point). ``declared`` is filled by
    :func:`validate`: the methods some experiment declares.
    """

    all: bool = False
    experiment: Sequence[str] | None = None
    objects: Sequence[str] | None = None
    problems: Sequence[str] | None = None
    problem_source: str = "shipped"
    methods: Sequence[str] | None = None
    grid: Mapping[str, Any] | None = None
    trials: int | None = None
    rollouts: int | None = None
    horizon: int | None = None
    seed: int = 0
    smoke: bool = False
    overwrite: bool = False
    out: str | None = None
    no_reuse: bool = False
    devices: int | None = None
    dry_run: bool = False
    compile_cache: str | None = None
    quiet: bool = False
    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    declared: frozenset[str] = frozenset()

    @classmethod
    def from_namespace(cls, a: Any) -> SweepConfig:
        """The configuration of parsed command-line arguments (grid items still
        ``NAME=V1,V2`` strings; :func:`validate` parses them)."""
        names = {f.name for f in dataclasses.fields(cls)} - {"declared"}
        return cls(**{n: getattr(a, n) for n in names if hasattr(a, n)})


def _split_commas(values: Iterable[str] | None) -> list[str] | None:
    if values is None:
        return None
    if isinstance(values, str):
        values = [values]
    return [x for v in values for x in v.split(",") if x]


def parse_grid(items: Sequence[str] | Mapping[str, Any]) -> dict[str, tuple]:
    """``NAME=V1,V2 ...`` strings (or a mapping of name to values) -> the product
    of the values as zipped sequences, one entry per grid point."""
    axes: dict[str, list[float]] = {}
    if isinstance(items, Mapping):
        for name, values in items.items():
            vals = list(values) if isinstance(values, (list, tuple)) else [values]
            try:
                axes[name] = [float(v) for v in vals]
            except (TypeError, ValueError):
                msg = f"--grid: {name} takes numbers, got {vals!r}"
                raise ConfigError(msg) from None
            if not axes[name]:
                raise ConfigError(f"--grid: no value for {name}")
    else:
        for item in items:
            name, eq, text = item.partition("=")
            if not eq or not name or not text:
                raise ConfigError(f"--grid: expected NAME=V1,V2,..., got {item!r}")
            if name in axes:
                raise ConfigError(f"--grid: {name} given twice")
            try:
                axes[name] = [float(x) for x in text.split(",") if x]
            except ValueError:
                msg = f"--grid: {name} takes numbers, got {text!r}"
                raise ConfigError(msg) from None
            if not axes[name]:
                raise ConfigError(f"--grid: no value for {name}")
    points = list(itertools.product(*axes.values()))
    return {n: tuple(pt[i] for pt in points) for i, n in enumerate(axes)}


def _check_problem_file(f: str) -> None:
    if not Path(f).is_file():
        raise ConfigError(f"--problems: no such file: {f}")

    suffix = Path(f).suffix.lower()
    if suffix in _MESH_SUFFIXES | {".urdf"}:
        raise ConfigError(
            f"--problems takes problem files (.npz); {f} is a mesh: build its "
            f"problem first with `python -m precompute --mesh {f} --units mm` "
            "(say the mesh's units), then pass the .npz file it prints"
        )
    if suffix != ".npz":
        raise ConfigError(
            "--problems takes problem files (.npz, as `python -m precompute "
            f"--mesh` writes them); {f} is not one"
        )


def validate(c: SweepConfig) -> SweepConfig:
    """The normalised configuration, or a :class:`ConfigError` naming what is
    wrong. Problem files alone run the ``main`` experiment."""
    names = experiments.EXPERIMENTS
    exps = [c.experiment] if isinstance(c.experiment, str) else c.experiment
    exps = list(exps) if exps else None
    if c.all and exps:
        raise ConfigError("use either --all or --experiment, not both")
    problems = [c.problems] if isinstance(c.problems, str) else c.problems
    if problems and not c.all and not exps and not c.smoke:
        exps = ["main"]  # problem files alone: the main configuration
    if not c.all and not exps and not c.smoke:
        raise ConfigError("nothing to run: pass --all, --experiment NAME or --smoke")
    for e in exps or ():
        if e not in names:
            near = difflib.get_close_matches(e, names, n=1)
            hint = f"; did you mean {near[0]}?" if near else ""
            raise ConfigError(
                f"unknown experiment '{e}' (known: {', '.join(names)}){hint}"
            )
    methods_ = _split_commas(c.methods)
    if methods_ is not None and not methods_:
        raise ConfigError("--methods: no method named")
    from legs_jax.core import methods  # jax: not at sweep start-up

    known = methods.names()
    for m in methods_ or ():
        if m not in known and ":" not in m:
            near = difflib.get_close_matches(m, known, n=1)
            hint = f"; did you mean {near[0]}?" if near else ""
            raise ConfigError(
                f"unknown method '{m}' (known: {', '.join(known)}; or "
                f"module.path:ATTRIBUTE for a method of your own){hint}"
            )
    grid = parse_grid(c.grid) if c.grid else None
    if grid is not None and not methods_:
        raise ConfigError("--grid needs --methods: the methods to run on the grid")
    objects = [c.objects] if isinstance(c.objects, str) else c.objects
    if objects and problems:
        raise ConfigError("use either --objects or --problems, not both")
    for f in problems or ():
        _check_problem_file(str(f))
    if c.problem_source not in ("shipped", "built"):
        raise ConfigError(
            f"--problem-source: shipped or built, got {c.problem_source!r}"
        )
    dist = (c.coordinator, c.num_processes, c.process_id)
    if any(x is not None for x in dist) and not all(x is not None for x in dist):
        raise ConfigError("--coordinator, --num-processes and --process-id go together")
    if c.num_processes is not None and c.process_id >= c.num_processes:
        raise ConfigError(f"--process-id must be < --num-processes ({c.num_processes})")
    for name in ("trials", "rollouts", "horizon", "devices", "num_processes"):
        v = getattr(c, name)
        if v is not None and (not isinstance(v, int) or v < 1):
            raise ConfigError(f"--{name.replace('_', '-')} must be >= 1, got {v!r}")
    if not isinstance(c.seed, int) or c.seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {c.seed!r}")
    return dataclasses.replace(
        c,
        experiment=exps,
        objects=list(objects) if objects else None,
        problems=[str(p) for p in problems] if problems else None,
        methods=methods_,
        grid=grid,
        declared=frozenset(experiments.declared_methods()),
    )


def own_configuration(c: SweepConfig) -> list[str]:
    """What makes a configuration differ from the experiments' declared one, as
    short words for a folder name (empty: the declared configuration)."""

    def names(values) -> str:
        return "+".join(str(v).replace(":", ".").replace("/", "_") for v in values)

    parts = []
    if c.objects:
        parts.append(names(c.objects))
    if c.problems:
        parts.append(names(Path(f).stem for f in c.problems))
    if c.methods:
        parts.append(names(c.methods))
    if c.grid:
        parts.append("grid-" + names(c.grid))
    for field, letter in (("trials", "T"), ("rollouts", "R"), ("horizon", "H")):
        if getattr(c, field):
            parts.append(f"{letter}{getattr(c, field)}")
    if c.seed:
        parts.append(f"seed{c.seed}")
    if c.problem_source != "shipped":
        parts.append(c.problem_source)
    return parts


def default_out(c: SweepConfig) -> Path:
    """Where a sweep writes without ``out``: ``results`` at the experiments'
    declared configuration, else a folder of its own under ``runs/`` named from
    what differs (``runs/main-bar_clamp-legs+tql``), so that a user's sweep never
    meets the shipped results."""
    if c.smoke:
        return Path(RUNS) / "smoke"
    parts = own_configuration(c)
    if not parts:
        return Path(RESULTS)
    exps = "all" if c.all else "+".join(dict.fromkeys(c.experiment or ()))
    slug = "-".join([exps, *parts])
    if len(slug) > _SLUG_MAX:
        digest = hashlib.sha256(slug.encode()).hexdigest()[:8]
        slug = f"{slug[: _SLUG_MAX - 9]}-{digest}"
    return Path(RUNS) / slug
