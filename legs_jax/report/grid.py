"""The report of a hyperparameter grid: the final gap against each grid axis.

A sweep run with ``--grid NAME=V1,V2 ...`` gives each arm several settings of its
hyperparameters. Table I and the experiments' own analyses need one setting per
arm, so a grid that its experiment does not declare is reported here instead: per
data set and grid point, the mean and standard error across objects of each
object's mean final gap (the aggregation of Table I), the same per object over its
T x R runs, and a figure — a line per arm over one axis, a heatmap for two.

The numbers are pure functions of ``runs.parquet`` (:func:`grid_axes`,
:func:`grid_tables`); :func:`grid_step` and :func:`grid_section` are the report's
step and section.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from legs_jax.report import analysis as an
from legs_jax.report import document as rp
from legs_jax.report.plotting import pyplot, save_figure, write_csv
from legs_jax.results import run_columns_besides_hparams

__all__ = [
    "declared_axes",
    "grid_axes",
    "grid_figure",
    "grid_section",
    "grid_table",
    "grid_tables",
    "user_grid",
]


def declared_axes(
    arms: Sequence[tuple[str, str, Mapping[str, Any]]],
) -> dict[tuple[str, str], frozenset[str]]:
    """(method, variant) -> the hyperparameters an experiment's declared arms
    (``ARMS`` of its ``sweep.py``) give several values."""
    out: dict[tuple[str, str], frozenset[str]] = {}
    for method, variant, hp in arms:
        several = {k for k, v in hp.items() if isinstance(v, (tuple, list))}
        out[(method, variant)] = out.get((method, variant), frozenset()) | several
    return out


def _distinct_per_arm(runs: pd.DataFrame) -> pd.DataFrame:
    """Per arm (method, variant), how many values each hyperparameter column of
    ``runs`` takes (every numeric column that is not a run's name or result)."""
    not_hparams = run_columns_besides_hparams()
    hp = [
        c
        for c in runs.columns
        if c not in not_hparams and pd.api.types.is_numeric_dtype(runs[c])
    ]
    return runs.groupby(["method", "variant"], sort=False)[hp].nunique()


def grid_axes(runs: pd.DataFrame) -> list[str]:
    """The hyperparameter columns that take several values within one arm
    (method, variant), in column order."""
    if runs.empty:
        return []
    n = _distinct_per_arm(runs)
    return [c for c in n.columns if int(n[c].max()) > 1]


def user_grid(
    runs: pd.DataFrame, arms: Sequence[tuple[str, str, Mapping[str, Any]]]
) -> list[str]:
    """The grid axes of ``runs`` that its experiment's declaration (``arms``) does
    not vary: empty when the experiment's own analysis applies."""
    if runs.empty:
        return []
    declared = declared_axes(arms)
    n = _distinct_per_arm(runs)
    extra = {
        c
        for (method, variant), row in n.iterrows()
        for c in n.columns
        if int(row[c]) > 1 and c not in declared.get((method, variant), frozenset())
    }
    return [c for c in n.columns if c in extra]


def grid_tables(runs: pd.DataFrame, axes: Sequence[str]) -> dict[str, pd.DataFrame]:
    """``per_object``: per object, arm and grid point, the mean and standard error
    of the final gap over its runs (``n_runs``); ``per_set``: per data set, arm and
    grid point, the mean and standard error across objects of those means
    (``n_objects``). Rows in the runs' order of sets and arms, grid points
    ascending."""
    if runs.empty:
        raise an.AnalysisError("runs.parquet has no rows")
    axes = list(axes)
    keys = ["set", "object", "method", "variant", *axes]
    obj = (
        runs.groupby(keys, sort=False)["final_gap"]
        .agg(n_runs="size", gap_mean="mean", gap_se=an._se)
        .reset_index()
    )
    set_keys = ["set", "method", "variant", *axes]
    per_set = (
        obj.groupby(set_keys, sort=False)["gap_mean"]
        .agg(n_objects="size", mean="mean", se=an._se)
        .reset_index()
    )
    set_rank = {s: i for i, s in enumerate(an.order_sets(runs["set"]))}
    arm_rank = {
        a: i
        for i, a in enumerate(
            dict.fromkeys(zip(runs["method"], runs["variant"], strict=True))
        )
    }

    def order(df: pd.DataFrame, inner: Sequence[str]) -> pd.DataFrame:
        key = df.assign(
            _s=df["set"].map(set_rank),
            _a=[arm_rank[a] for a in zip(df["method"], df["variant"], strict=True)],
        )
        return (
            key.sort_values(["_s", "_a", *inner, *axes], kind="stable")
            .drop(columns=["_s", "_a"])
            .reset_index(drop=True)
        )

    return {
        "per_set": order(per_set, []),
        "per_object": order(obj, ["object"]),
    }


def _point(row: Mapping[str, Any], axes: Sequence[str]) -> str:
    return ", ".join(f"{a} = {float(row[a]):g}" for a in axes)


def _arm_label(method: str, variant: str) -> str:
    return an.Arms().label(method, variant)


def grid_table(df: pd.DataFrame, axes: Sequence[str], experiment: str) -> rp.Table:
    """The Markdown/LaTeX table of :func:`grid_tables`' ``per_set`` (mean ± SE
    across objects) or ``per_object`` (mean ± SE over an object's runs)."""
    per_object = "object" in df.columns
    name, count, mean, se = (
        ("Object", "n_runs", "gap_mean", "gap_se")
        if per_object
        else (None, "n_objects", "mean", "se")
    )
    header = ["Set", *([name] if name else []), "Method", *axes]
    header += ["Runs" if per_object else "Objects", "Final gap"]
    rows = []
    for _, r in df.iterrows():
        rows.append(
            [
                an.SET_LABELS.get(r["set"], r["set"]),
                *([str(r["object"])] if per_object else []),
                _arm_label(r["method"], r["variant"]),
                *[f"{float(r[a]):g}" for a in axes],
                str(int(r[count])),
                rp.Num(float(r[mean]), float(r[se]), 3, False),
            ]
        )
    what = "per object " if per_object else ""
    return rp.Table(
        header,
        rows,
        ("lll" if per_object else "ll") + "c" * len(axes) + "rc",
        caption=f"Final optimality gap {what}over the grid ({experiment})",
        label=f"tab:grid-{'per-object-' if per_object else ''}{experiment}",
        notes=[
            "Mean ± standard error of the final gap over the object's runs."
            if per_object
            else "Mean ± standard error across objects of each object's mean final "
            "gap over its T × R runs (Table I's aggregation), at every grid point."
        ],
    )


def grid_figure(per_set: pd.DataFrame, axes: Sequence[str], path: Path) -> Path:
    """One panel per data set (and arm, for a heatmap): the final gap over the grid.
    One axis: a line per arm with ± 1 SE bars; two: a heatmap per arm; more: lines
    over the first axis, one per setting of the others."""
    plt = pyplot()
    sets = an.order_sets(per_set["set"])
    arms = list(dict.fromkeys(zip(per_set["method"], per_set["variant"], strict=True)))
    if len(axes) == 2:
        x_ax, y_ax = axes
        panels = [(s, a) for s in sets for a in arms]
        fig, axs = plt.subplots(
            1,
            len(panels),
            figsize=(3.6 * len(panels) + 1.0, 3.4),
            squeeze=False,
            constrained_layout=True,
        )
        vmin, vmax = float(per_set["mean"].min()), float(per_set["mean"].max())
        for ax, (s, (m, v)) in zip(axs[0], panels, strict=True):
            d = per_set[
                (per_set["set"] == s)
                & (per_set["method"] == m)
                & (per_set["variant"] == v)
            ]
            xs = sorted(d[x_ax].unique())
            ys = sorted(d[y_ax].unique())
            grid = np.full((len(ys), len(xs)), np.nan)
            for _, r in d.iterrows():
                grid[ys.index(r[y_ax]), xs.index(r[x_ax])] = r["mean"]
            im = ax.imshow(grid, origin="lower", cmap="viridis_r", vmin=vmin, vmax=vmax)
            mid = 0.5 * (vmin + vmax)
            for (i, j), val in np.ndenumerate(grid):
                if np.isfinite(val):  # dark cells (high gaps) get white text
                    ax.text(
                        j, i, f"{val:.3f}", ha="center", va="center", fontsize=7,
                        color="white" if val > mid else "black",
                    )  # fmt: skip
            ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs])
            ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
            ax.set_xlabel(x_ax)
            ax.set_ylabel(y_ax)
            ax.set_title(f"{an.SET_LABELS.get(s, s)}\n{_arm_label(m, v)}")
        fig.colorbar(im, ax=axs[0].tolist(), label="mean final gap", shrink=0.85)
    else:
        x_ax, rest = axes[0], list(axes[1:])
        fig, axs = plt.subplots(
            1, len(sets), figsize=(4.2 * len(sets), 3.2), squeeze=False
        )
        for ax, s in zip(axs[0], sets, strict=True):
            d = per_set[per_set["set"] == s]
            others = (
                [()]
                if not rest
                else list(itertools.product(*[sorted(d[c].unique()) for c in rest]))
            )
            for (m, v), combo in itertools.product(arms, others):
                sel = (d["method"] == m) & (d["variant"] == v)
                for c, val in zip(rest, combo, strict=True):
                    sel &= d[c] == val
                line = d[sel].sort_values(x_ax)
                if line.empty:
                    continue
                label = _arm_label(m, v) + "".join(
                    f", {c} = {val:g}" for c, val in zip(rest, combo, strict=True)
                )
                if len(line) == 1:  # an arm off the grid: its level, for reference
                    ax.axhline(
                        float(line["mean"].iloc[0]),
                        ls="--",
                        lw=1.1,
                        color="#777777",
                        label=f"{label} (not on the grid)",
                    )
                    continue
                ax.errorbar(
                    line[x_ax],
                    line["mean"],
                    yerr=line["se"].fillna(0.0),
                    marker="o",
                    ms=3.5,
                    capsize=2,
                    lw=1.3,
                    label=label,
                )
            ax.set_xlabel(x_ax)
            ax.set_ylabel("mean final gap")
            ax.set_title(an.SET_LABELS.get(s, s))
            ax.legend(frameon=False)
        fig.tight_layout()
    return save_figure(fig, path)


def grid_step(experiment: str, axes: Sequence[str]):
    """The report step of a grid of ``experiment``: its tables (``.md``, ``.tex``,
    ``.csv``) and figure, kept in the report's context under ``grid:<name>``."""

    def step(run) -> None:
        runs = run.res.table(experiment, "runs")
        t = grid_tables(runs, axes)
        stem = f"grid_{experiment}"
        files = rp.write_pair(
            stem, grid_table(t["per_set"], axes, experiment), run.tables
        )
        files.append(write_csv(t["per_set"], run.tables / f"{stem}.csv"))
        files += rp.write_pair(
            f"{stem}_per_object",
            grid_table(t["per_object"], axes, experiment),
            run.tables,
        )
        files.append(write_csv(t["per_object"], run.tables / f"{stem}_per_object.csv"))
        files.append(grid_figure(t["per_set"], axes, run.figures / f"{stem}.png"))
        run.written.extend(files)
        run.ctx[f"grid:{experiment}"] = dict(
            axes=list(axes),
            per_set=t["per_set"],
            per_object=t["per_object"],
            horizon=int(runs["horizon"].max()) if "horizon" in runs else None,
            tables=run.tables,
            figures=run.figures,
            out=run.ctx["out"],
        )

    return step


def _best_lines(
    per_set: pd.DataFrame, per_object: pd.DataFrame, axes: Sequence[str]
) -> list[str]:
    """Per set and arm: the grid point of lowest mean gap, and whether it is
    better than every other point by more than noise. The points are compared
    paired by object (the same objects and, at every grid point, the same random
    numbers): the difference of each object's mean gap from the best point's,
    its mean and standard error across objects."""
    lines = []
    for (s, m, v), d in per_set.groupby(["set", "method", "variant"], sort=False):
        if len(d) < 2:
            continue
        best = d.loc[d["mean"].idxmin()]
        objs = per_object[
            (per_object["set"] == s)
            & (per_object["method"] == m)
            & (per_object["variant"] == v)
        ]
        wide = objs.pivot_table(index="object", columns=list(axes), values="gap_mean")
        key = tuple(best[a] for a in axes) if len(axes) > 1 else best[axes[0]]
        diffs = wide.sub(wide[key], axis=0).drop(columns=[key])
        mean = diffs.mean(axis=0)
        se = diffs.std(axis=0, ddof=1) / np.sqrt(diffs.count(axis=0))
        ratio = (mean / se.replace(0.0, np.nan)).fillna(np.inf)
        rival = ratio.idxmin()
        rival_pt = dict(zip(axes, rival if len(axes) > 1 else (rival,), strict=True))
        resolved = bool((mean >= 2.0 * se).all()) and bool(np.isfinite(se).all())
        lines.append(
            f"- {an.SET_LABELS.get(s, s)}, {_arm_label(m, v)}: lowest mean gap "
            f"{rp.fmt(float(best['mean']))} at {_point(best, axes)}. Paired by "
            f"object, the nearest other setting ({_point(rival_pt, axes)}) is "
            f"{rp.fmt(float(mean[rival]))} ± {rp.fmt(float(se[rival]))} worse"
            + (
                ", and every other setting is worse by more than two standard errors."
                if resolved
                else ": these runs do not tell the best settings apart."
            )
        )
    return lines


def grid_section(experiment: str):
    """The report's section on a grid of ``experiment``."""

    def section(ctx: Mapping[str, Any]) -> list[str]:
        g = ctx.get(f"grid:{experiment}")
        title = f"## Grid: {experiment} over {', '.join(ctx_axes(ctx, experiment))}"
        if g is None:
            return [title, "", "_Not available: the grid's tables failed._", ""]
        rel = _relative(g["figures"], g["out"])
        rel_t = _relative(g["tables"], g["out"])
        L = [
            title,
            "",
            f"Final optimality gap at {rp.horizon_text(g['horizon'])} at every grid "
            "point (mean ± SE across objects; per object in "
            f"[`{rel_t}/grid_{experiment}_per_object.md`]"
            f"({rel_t}/grid_{experiment}_per_object.md)).",
            "",
            f"![final gap over the grid]({rel}/grid_{experiment}.png)",
            "",
            rp.to_markdown(grid_table(g["per_set"], g["axes"], experiment)),
        ]
        L += _best_lines(g["per_set"], g["per_object"], g["axes"])
        L.append("")
        return L

    return section


def ctx_axes(ctx: Mapping[str, Any], experiment: str) -> list[str]:
    g = ctx.get(f"grid:{experiment}")
    return list(g["axes"]) if g else []


def _relative(path: Path, base: Path) -> str:
    try:
        return str(Path(path).relative_to(Path(base)))
    except ValueError:
        return str(path)
