"""The paper's tables and figures, and the reproduction report, from saved results.

The outputs of each experiment are made by its own ``experiments/<name>/analysis.py``
(``STEPS``, and ``SECTIONS`` of the report); this module holds the driver, the CLI,
the result and object readers and the plotting helpers they share.

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
An output whose results are missing is skipped with a message naming the missing
file, and the exit status is then 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

import experiments
from legs_jax.report import analysis as an
from legs_jax.report import document as rp

__all__ = [
    "MissingResults",
    "ObjectData",
    "Results",
    "Run",
    "appendix_step",
    "appendix_tables",
    "generate",
    "main",
    "method_style",
    "note_on_axes",
    "pyplot",
    "save_figure",
    "set_label",
    "write_csv",
]

_PROG = "python -m legs_jax.figures"
_DESCRIPTION = (
    "Regenerate the paper's tables and figures from saved sweep results "
    "(never reruns a sweep): Table I with win counts, per-object gaps, "
    "Fig. 3 case study, Fig. 4 early stopping, the two appendix tables, "
    "the active-set evolution of one LEGS rollout, and REPORT.md with "
    "every number beside the paper's. Outputs whose results are missing "
    "are skipped with a message naming the missing file (exit status 1)."
)

EXPERIMENTS = experiments.EXPERIMENTS

_PNG_META = {"Software": None}
_DPI = 150


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

    def __init__(self, root: str | Path, results: Results):
        self.root = Path(root)
        self.results = results
        self._problems: dict[str, Any] = {}
        self._meshes: dict[str, Any] = {}

    def problem(self, set_: str, name: str):
        """(Problem or None, reason)."""
        key = f"{set_}/{name}"
        if key not in self._problems:
            from legs_jax.core import problem as problem_mod

            # the file the results were made from first, then the shipped set's,
            # then a build's
            candidates = []
            for exp in EXPERIMENTS:
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
            from legs_jax.report import render

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
def pyplot():
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        try:
            matplotlib.use("Agg")
        except Exception:  # noqa: BLE001 - keep the current backend
            pass
    import matplotlib.pyplot as plt

    plt.rcParams.update(
        {
            "font.size": 9,
            "axes.titlesize": 10,
            "axes.labelsize": 9,
            "legend.fontsize": 8.5,
            "xtick.labelsize": 8,
            "ytick.labelsize": 8,
            "axes.spines.top": False,
            "axes.spines.right": False,
        }
    )
    return plt


def save_figure(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI, metadata=_PNG_META, facecolor="white")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


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
def write_csv(df: pd.DataFrame, path: Path) -> Path:
    rp.write_text(path, rp.to_csv(df))
    return path


def appendix_tables(
    res: Results, out: Path, spec: rp.Appendix
) -> tuple[list[Path], dict[str, Any]]:
    """The table of an appendix experiment (``spec``): ``<experiment>.md``,
    ``.tex`` and ``.csv``."""
    experiment, param = spec.experiment, spec.param
    method = experiments.get(experiment).ARMS[0][0]  # the one method of the sweep
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
        cls, results: str | Path, out: str | Path, data: str | Path, **options: Any
    ) -> Run:
        """A run that reads ``results`` and the objects under ``data`` and writes
        into ``out/tables`` and ``out/figures``; nothing written yet."""
        res, out = Results(results), Path(out)
        return cls(
            res=res,
            objects=ObjectData(data, res),
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


def plan_report(res: Results) -> tuple[list, list]:
    """The steps and report sections for the experiments present in ``res``: each
    experiment's own (its ``analysis.py``), or, for results that vary a
    hyperparameter its declaration does not (a ``--grid`` sweep), the grid's
    (:mod:`legs_jax.report.grid`). An experiment with no results contributes
    nothing; the report lists it as not run."""
    from legs_jax.report import grid

    steps: list = []
    sections: list = []
    for name in EXPERIMENTS:
        if not res.has(name, "runs"):
            continue
        mod = experiments.analysis(name)
        try:
            axes = grid.user_grid(res.table(name, "runs"), experiments.get(name).ARMS)
        except MissingResults:
            axes = []
        if axes:
            steps.append((f"grid: {name}", grid.grid_step(name, axes)))
            own = [pos for pos, _ in getattr(mod, "SECTIONS", ())] or [99]
            sections.append((min(own), grid.grid_section(name)))
            continue
        steps += list(getattr(mod, "STEPS", ()))
        sections += list(getattr(mod, "SECTIONS", ()))
    return steps, sections


def generate(
    results: str | Path = "results",
    out: str | Path | None = None,
    data: str | Path = "data",
    *,
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
    if not any(res.has(e, "runs") for e in EXPERIMENTS):
        raise MissingResults(
            f"no results in {results}: none of "
            + ", ".join(f"{e}/runs.parquet" for e in EXPERIMENTS)
            + " exists (run `python -m legs_jax.sweep --all` first, or pass "
            "--results)"
        )
    out = Path(out) if out is not None else results
    run = Run.start(
        results, out, data, case_objects=case_objects, active_object=active_object
    )
    problems: list[str] = []
    steps, sections = plan_report(res)
    run.ctx["sections"] = sections
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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=_PROG, description=_DESCRIPTION)
    p.add_argument(
        "--results",
        default="results",
        metavar="DIR",
        help="folder holding <experiment>/runs.parquet etc. (default: results)",
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="write tables/, figures/ and REPORT.md here (default: the results folder)",
    )
    p.add_argument(
        "--data",
        default="data",
        metavar="DIR",
        help="folder with meshes/<set>/<name>.obj and problems/<set>/<name>.npz "
        "for drawing objects (default: data)",
    )
    p.add_argument(
        "--case-objects",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help="objects of Fig. 3 (default: the case_study experiment's objects)",
    )
    p.add_argument(
        "--active-object",
        default=None,
        metavar="NAME",
        help="object whose LEGS active set is drawn (default: the case-study "
        "object whose active set changes most)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar or listing")
    p.add_argument(
        "--debug",
        action="store_true",
        help="stop with a traceback when an output fails unexpectedly",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    try:
        written, problems = generate(
            a.results,
            a.out,
            a.data,
            case_objects=a.case_objects,
            active_object=a.active_object,
            progress=not a.quiet,
            debug=a.debug,
        )
    except MissingResults as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not a.quiet:
        for p in written:
            print(f"wrote {p}")
    for msg in problems:
        print(f"error: {msg}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
