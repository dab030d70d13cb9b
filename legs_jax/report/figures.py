"""The paper's tables and figures, and the reproduction report, from saved results.

The outputs of each experiment are made by its own analysis (``STEPS``, and
``SECTIONS`` of the report), which the caller passes in (:class:`Experiment`;
``python -m legs_jax.figures`` passes the paper's, from ``experiments/``); this
module holds the driver (:func:`generate`), the result and object readers and the
plotting helpers they share.

``python -m legs_jax.figures [--results DIR] [--out DIR] [--data DIR]`` reads the
tidy tables a sweep wrote under ``DIR/<experiment>/`` and never reruns anything.
It writes, under ``--out`` (default: the results folder):

- ``tables/``: Table I and the win counts (``table1``, ``wins``), the final gap of
  every method on every object (``per_object``), early stopping
  (``early_stopping``, ``early_stopping_per_object``, ``sensitivity``) and the two
  appendix tables (``prior_strength``, ``confidence``), each as ``.md`` and
  ``.tex`` (and ``.csv`` at full precision where useful);
- ``figures/``: Fig. 3 (``fig3_case_study.png``), Fig. 4
  (``fig4_early_stopping.png``) and the active-set evolution of one LEGS rollout
  (``fig1_active_set.png``);
- ``REPORT.md``: every number beside the paper's, the figures, a discussion.

Objects are drawn from ``<data>/meshes/<set>/<name>.obj`` in the stable pose of
``<data>/problems/<set>/<name>.npz``; what is missing is said in the figure.
An experiment without results is listed in the report as not run; an output of
an experiment that ran whose results are missing is skipped with a message naming
the missing file, and the exit status is then 1. A folder whose results vary a
hyperparameter the experiment does not declare (a ``--grid`` sweep) is reported
against the grid's axes (:mod:`legs_jax.report.grid`).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import pandas as pd

from legs_jax.core import problem as problem_mod
from legs_jax.report import analysis as an
from legs_jax.report import document as rp
from legs_jax.report import grid, render
from legs_jax.report.plotting import pyplot, save_figure, write_csv

__all__ = [
    "MissingResults",
    "ObjectData",
    "Results",
    "Run",
    "appendix_step",
    "appendix_tables",
    "Experiment",
    "generate",
    "method_style",
    "note_on_axes",
    "pyplot",
    "save_figure",
    "set_label",
    "write_csv",
]


class Experiment(NamedTuple):
    """What the report needs of one experiment: its ``name``, its declared
    ``arms`` (method, variant, hyperparameters; a tuple value is a declared grid),
    and its analysis: ``steps`` (label, function of a :class:`Run`) that write
    its tables and figures, and ``sections`` (position, function of the report's
    context) that write its parts of REPORT.md. The caller passes them in, in the
    report's order (``experiments.for_report()`` gives the paper's)."""

    name: str
    arms: tuple = ()
    steps: tuple = ()
    sections: tuple = ()


class MissingResults(Exception):
    """A results file that an output needs does not exist (or cannot be read)."""


# ===================================================================== inputs
class Results:
    """Lazy, cached access to ``<root>/<experiment>/<table>.parquet``."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self._cache: dict[tuple[str, str], pd.DataFrame] = {}

    def path(self, experiment: str, table: str) -> Path:
        return self.root / experiment / f"{table}.parquet"

    def has(self, experiment: str, table: str) -> bool:
        return self.path(experiment, table).is_file()

    def table(self, experiment: str, table: str) -> pd.DataFrame:
        key = (experiment, table)
        if key not in self._cache:
            p = self.path(experiment, table)
            if not p.is_file():
                raise MissingResults(
                    f"{p} is missing (run `python -m legs_jax.sweep --experiment "
                    f"{experiment}`)"
                )
            try:
                df = pd.read_parquet(p)
            except Exception as e:  # noqa: BLE001 - any unreadable file
                raise MissingResults(f"{p} cannot be read: {e}") from None
            for c in ("experiment", "set", "object", "method", "variant"):
                if c in df.columns:
                    df[c] = df[c].astype(object).where(df[c].notna(), "").astype(str)
            self._cache[key] = df
        return self._cache[key]

    def manifest(self, experiment: str) -> dict[str, Any]:
        p = self.root / experiment / "manifest.json"
        if not p.is_file():
            return {}
        try:
            with open(p) as fh:
                return json.load(fh)
        except (OSError, json.JSONDecodeError):
            return {}

    def horizon(self, experiment: str) -> int:
        runs = self.table(experiment, "runs")
        if "horizon" in runs.columns and len(runs):
            return int(runs["horizon"].max())
        cfg = self.manifest(experiment).get("config", {})
        if "horizon" in cfg:
            return int(cfg["horizon"])
        raise MissingResults(f"{self.path(experiment, 'runs')}: no horizon recorded")

    def object_sets(self) -> dict[str, str]:
        """object -> set over every experiment's runs or objects table."""
        out: dict[str, str] = {}
        if not self.root.is_dir():
            return out
        for d in sorted(p for p in self.root.iterdir() if p.is_dir()):
            for t in ("objects", "runs"):
                if self.has(d.name, t):
                    try:
                        df = self.table(d.name, t)
                    except MissingResults:
                        continue
                    if {"object", "set"} <= set(df.columns):
                        pairs = df[["object", "set"]].drop_duplicates()
                        for o, s in zip(pairs["object"], pairs["set"], strict=True):
                            out.setdefault(o, s)
        return out


class ObjectData:
    """Meshes and problem files of the objects (for drawing), with the reason
    when one is unavailable."""

    def __init__(self, root: str | Path, results: Results, order: Sequence[str] = ()):
        self.root = Path(root)
        self.results = results
        self.order = tuple(order)  # experiments whose problem files come first
        self._problems: dict[str, Any] = {}
        self._meshes: dict[str, Any] = {}

    def problem(self, set_: str, name: str):
        """(Problem or None, reason)."""
        key = f"{set_}/{name}"
        if key not in self._problems:
            # the file the results were made from first, then the shipped set's,
            # then a build's
            candidates = []
            for exp in self.order:
                if self.results.has(exp, "objects"):
                    obj = self.results.table(exp, "objects")
                    if "problem_file" in obj.columns:
                        hit = obj.loc[obj["object"] == name, "problem_file"]
                        candidates += [Path(p) for p in hit if p]
            candidates += [
                self.root / "problemset" / set_ / f"{name}.npz",
                self.root / "problems" / set_ / f"{name}.npz",
            ]
            found = None
            reason = f"problem file {candidates[0]} missing"
            for c in candidates:
                if c.is_file():
                    try:
                        found = problem_mod.load(c)
                        break
                    except Exception as e:  # noqa: BLE001
                        reason = f"problem file unreadable ({e})"
            self._problems[key] = (found, "" if found is not None else reason)
        return self._problems[key]

    def mesh(self, set_: str, name: str):
        """(trimesh.Trimesh or None, reason)."""
        key = f"{set_}/{name}"
        if key not in self._meshes:
            path = self.root / "meshes" / set_ / f"{name}.obj"
            if not path.is_file():
                self._meshes[key] = (None, f"mesh {path} missing")
            else:
                try:
                    self._meshes[key] = (render.load_mesh(path), "")
                except Exception as e:  # noqa: BLE001
                    self._meshes[key] = (None, f"mesh unreadable ({e})")
        return self._meshes[key]


# ================================================================ plot helpers
def method_style(method: str, variant: str, arms: an.Arms) -> dict[str, Any]:
    """The arm's declared line style (its method's, or its variant's)."""
    style = arms.declaration(method, variant).get("style")
    return dict(style or dict(color="#8c564b", ls="-", lw=1.4))


def note_on_axes(ax, text: str) -> None:
    ax.text(
        0.5,
        0.5,
        text,
        ha="center",
        va="center",
        fontsize=8,
        color="#555555",
        wrap=True,
        transform=ax.transAxes,
    )


def set_label(set_: str) -> str:
    return an.SET_LABELS.get(set_, set_)


# ======================================================================= Fig. 3


# ======================================================================= Fig. 4


# ================================================================ active set


# ==================================================================== tables


def appendix_tables(
    res: Results, out: Path, spec: rp.Appendix
) -> tuple[list[Path], dict[str, Any]]:
    """The table of an appendix experiment (``spec``): ``<experiment>.md``,
    ``.tex`` and ``.csv``."""
    experiment, param, method = spec.experiment, spec.param, spec.method
    runs = an.select_arm(res.table(experiment, "runs"), method, "", vary=(param,))
    if runs.empty:
        raise MissingResults(f"{res.path(experiment, 'runs')} has no LEGS runs")
    table = an.sweep_table(runs, param)
    other = spec.other
    vals = runs[other].unique() if other in runs.columns else []
    fixed = float(vals[0]) if len(vals) == 1 else None
    horizon = int(runs["horizon"].max()) if "horizon" in runs.columns else None
    text = rp.appendix_table(table, spec, fixed, horizon)
    files = rp.write_pair(experiment, text, out)
    files.append(write_csv(table, out / f"{experiment}.csv"))
    return files, dict(table=table, fixed=fixed, horizon=horizon)


# ==================================================================== driver
@dataclasses.dataclass
class Run:
    """What the steps of an experiment's analysis (``experiments/<name>/analysis.py``,
    ``STEPS``) read and fill: the results, the object data for drawing, the folders
    to write into, the report's context and the list of files written."""

    res: Results
    objects: ObjectData
    tables: Path
    figures: Path
    ctx: dict[str, Any]
    written: list[Path]
    options: dict[str, Any]

    @classmethod
    def start(
        cls,
        results: str | Path,
        out: str | Path,
        data: str | Path,
        order: Sequence[str] = (),
        **options: Any,
    ) -> Run:
        """A run that reads ``results`` and the objects under ``data`` (problem
        files first from the experiments named in ``order``) and writes into
        ``out/tables`` and ``out/figures``; nothing written yet."""
        res, out = Results(results), Path(out)
        return cls(
            res=res,
            objects=ObjectData(data, res, order),
            tables=out / "tables",
            figures=out / "figures",
            ctx={"results": res, "out": out},
            written=[],
            options=dict(options),
        )


def appendix_step(spec: rp.Appendix) -> Callable[[Run], None]:
    """The step of an appendix experiment's analysis: its table
    (:func:`appendix_tables`), kept in the report's context under its name."""

    def step(run: Run) -> None:
        files, run.ctx[spec.experiment] = appendix_tables(run.res, run.tables, spec)
        run.written.extend(files)

    return step


def plan_report(res: Results, reported: Sequence[Experiment]) -> tuple[list, list]:
    """The steps and report sections for the experiments present in ``res``: each
    experiment's own, or, for results that vary a hyperparameter its declaration
    does not (a ``--grid`` sweep), the grid's (:mod:`legs_jax.report.grid`). An
    experiment with no results contributes nothing; the report lists it as not
    run."""
    steps: list = []
    sections: list = []
    for e in reported:
        if not res.has(e.name, "runs"):
            continue
        try:
            axes = grid.user_grid(res.table(e.name, "runs"), e.arms)
        except MissingResults:
            axes = []
        if axes:
            steps.append((f"grid: {e.name}", grid.grid_step(e.name, axes)))
            own = [pos for pos, _ in e.sections] or [99]
            sections.append((min(own), grid.grid_section(e.name)))
            continue
        steps += list(e.steps)
        sections += list(e.sections)
    return steps, sections


def generate(
    results: str | Path = "results",
    out: str | Path | None = None,
    data: str | Path = "data",
    *,
    experiments: Sequence[Experiment],
    case_objects: Sequence[str] | None = None,
    active_object: str | None = None,
    progress: bool = True,
    debug: bool = False,
) -> tuple[list[Path], list[str]]:
    """Write every table, figure and the report that the results allow: the steps
    of every experiment's analysis, in the experiments' order.

    ``case_objects`` and ``active_object`` choose the objects of Fig. 3 and of the
    active-set figure (default: the case study's objects, and the one whose active
    set changes most). Returns (files written, problems): each problem is one line
    naming what was missing and which output was skipped.
    """
    results = Path(results)
    if not results.is_dir():
        raise MissingResults(
            f"results directory {results} does not exist (run `python -m "
            "legs_jax.sweep --all` first, or pass --results)"
        )
    res = Results(results)
    names = [e.name for e in experiments]
    if not any(res.has(e, "runs") for e in names):
        raise MissingResults(
            f"no results in {results}: none of "
            + ", ".join(f"{e}/runs.parquet" for e in names)
            + " exists (run `python -m legs_jax.sweep --all` first, or pass "
            "--results)"
        )
    out = Path(out) if out is not None else results
    run = Run.start(
        results,
        out,
        data,
        names,
        case_objects=case_objects,
        active_object=active_object,
    )
    problems: list[str] = []
    steps, sections = plan_report(res, experiments)
    run.ctx["sections"] = sections
    run.ctx["experiments"] = names
    from tqdm import tqdm

    bar = tqdm(steps, desc="figures", disable=not progress, leave=False)
    for label, fn in bar:
        bar.set_postfix_str(label)
        try:
            fn(run)
        except (MissingResults, an.AnalysisError) as e:
            problems.append(f"{label}: skipped: {e}")
        except Exception as e:  # noqa: BLE001 - one bad output must not stop the rest
            if debug:
                raise
            problems.append(
                f"{label}: failed: {type(e).__name__}: {e} (rerun with --debug for "
                "the traceback)"
            )
    bar.close()
    run.ctx["problems"] = problems
    report_path = out / "REPORT.md"
    rp.write_text(report_path, rp.build_report(run.ctx))
    run.written.append(report_path)
    return run.written, problems
