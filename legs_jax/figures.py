"""The paper's tables and figures, and the reproduction report, from saved results.

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
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import experiments
from legs_jax import analysis as an
from legs_jax import report as rp

__all__ = [
    "CASE_OBJECTS",
    "MissingResults",
    "ObjectData",
    "Results",
    "active_set_figure",
    "case_study_figure",
    "early_stopping_figure",
    "generate",
    "main",
]

EXPERIMENTS = experiments.EXPERIMENTS
CASE_OBJECTS = tuple(experiments.get("case_study").OBJECTS)
# None: the case-study object whose LEGS active set changes most (the most
# distinct members on one pose), which shows the pruning best.
ACTIVE_OBJECT: str | None = None
DEFAULT_RHO = tuple(round(0.05 * i, 2) for i in range(1, 20))

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
            from legs_jax import problem as problem_mod

            candidates = [self.root / "problems" / set_ / f"{name}.npz"]
            for exp in ("case_study", "main"):
                if self.results.has(exp, "objects"):
                    obj = self.results.table(exp, "objects")
                    if "problem_file" in obj.columns:
                        hit = obj.loc[obj["object"] == name, "problem_file"]
                        candidates += [Path(p) for p in hit if p]
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
            from legs_jax import render

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
def _plt():
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


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI, metadata=_PNG_META, facecolor="white")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _style(method: str, variant: str) -> dict[str, Any]:
    """The arm's declared line style (its method's, or its variant's)."""
    style = an.arm_declaration(method, variant).get("style")
    return dict(style or dict(color="#8c564b", ls="-", lw=1.4))


def _note(ax, text: str) -> None:
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


def _set_label(set_: str) -> str:
    return an.SET_LABELS.get(set_, set_)


def _main_pose(pb) -> int:
    lam = np.where(pb.pose_valid, pb.landing, -1.0)
    return int(np.argmax(lam))


def _draw_object(
    ax,
    data: ObjectData,
    set_: str,
    name: str,
    pose: int | None = None,
    grasps: Callable | None = None,
    size: int = 300,
) -> dict[str, Any]:
    """Draw the object in a stable pose into ``ax``; returns what was drawn
    (``pose``, ``notes``). ``grasps(pb, pose, rendering, ax)`` draws on top."""
    from legs_jax import render

    ax.set_axis_off()
    info: dict[str, Any] = {"pose": pose, "notes": []}
    mesh, why_mesh = data.mesh(set_, name)
    pb, why_pb = data.problem(set_, name)
    if mesh is None:
        info["notes"].append(why_mesh)
        _note(ax, "no picture:\n" + _wrap_path(why_mesh))
        return info
    transform = None
    scale = 1.0
    if pb is not None and pose is not None and not 0 <= pose < pb.num_poses:
        info["notes"].append(
            f"problem file of {name} has {pb.num_poses} poses, results use pose {pose}"
        )
        pb = None
    if pb is not None and pb.meta.get("geometry") is False:
        why_pb = f"problem file of {name} has no grasp or pose geometry"
        pb = None
    if pb is not None:
        if pose is None:
            pose = _main_pose(pb)
        info["pose"] = pose
        transform = pb.pose_transform[pose]
        centers = pb.grasp_center[0, pose][pb.valid[0, pose]]
        scale = render.problem_scale(pb, mesh.vertices, transform, centers)
    else:
        info["notes"].append(why_pb)
    verts = render.pose_vertices(mesh.vertices, transform, scale)
    try:
        img = render.render(verts, mesh.faces, size=size)
    except Exception as e:  # noqa: BLE001 - drawing must not stop the report
        info["notes"].append(f"rendering failed ({e})")
        _note(ax, f"rendering failed:\n{e}")
        return info
    ax.imshow(img.image, interpolation="antialiased")
    ax.set_xlim(-0.5, img.size - 0.5)
    ax.set_ylim(img.size - 0.5, -0.5)
    if pb is None:
        ax.text(
            0.5,
            0.02,
            "pose unknown: problem file missing\n(mesh shown in its file frame)",
            ha="center",
            va="bottom",
            fontsize=7,
            color="#aa3333",
            transform=ax.transAxes,
        )
    elif grasps is not None:
        try:
            grasps(pb, pose, img, ax)
        except (IndexError, ValueError) as e:
            info["notes"].append(f"grasps of {name} not drawn ({e})")
    return info


def _wrap_path(text: str, width: int = 34) -> str:
    words, lines, cur = text.split(" "), [], ""
    for w in words:
        while len(w) > width:
            if cur:
                lines.append(cur)
                cur = ""
            lines.append(w[:width])
            w = w[width:]
        if len(cur) + len(w) + 1 > width and cur:
            lines.append(cur)
            cur = w
        else:
            cur = f"{cur} {w}".strip()
    if cur:
        lines.append(cur)
    return "\n".join(lines)


def _pose_count(data: ObjectData, res: Results, set_: str, name: str) -> int | None:
    pb, _ = data.problem(set_, name)
    if pb is not None:
        return int(pb.num_real_poses)
    for exp in ("case_study", "main"):
        if res.has(exp, "objects"):
            obj = res.table(exp, "objects")
            hit = obj.loc[obj["object"] == name]
            if len(hit) and "num_poses" in hit.columns:
                return int(hit["num_poses"].iloc[0])
    if res.has("case_study", "grasps"):
        g = res.table("case_study", "grasps")
        g = g[g["object"] == name]
        if len(g):
            return int(g["pose"].nunique())
    return None


def _reservoir(data: ObjectData, res: Results, set_: str, name: str):
    """(robustness [N], prior [N], landing-per-grasp [N], pose [N]) of trial 0."""
    if res.has("case_study", "grasps"):
        g = res.table("case_study", "grasps")
        g = g[g["object"] == name]
        if "trial" in g.columns and len(g):
            g = g[g["trial"] == g["trial"].min()]
        if len(g):
            prior = g["prior"].to_numpy(float) if "prior" in g.columns else None
            return g["robustness"].to_numpy(float), prior, g["pose"].to_numpy(int)
    pb, _ = data.problem(set_, name)
    if pb is not None:
        p, k = np.nonzero(pb.valid[0])
        return (
            pb.robustness[0][p, k].astype(float),
            pb.prior[0][p, k].astype(float),
            p,
        )
    return None


# ======================================================================= Fig. 3
def case_study_figure(
    res: Results,
    data: ObjectData,
    out: Path,
    objects: Sequence[str] = CASE_OBJECTS,
) -> tuple[Path, dict[str, Any]]:
    """Fig. 3: per object, the object in its most likely pose with the pose count,
    the histogram of ground-truth robustness, and every method's learning curve
    with a ±1 SE band."""
    exp = "case_study" if res.has("case_study", "curves") else "main"
    if not res.has(exp, "curves"):
        raise MissingResults(
            f"{res.path('case_study', 'curves')} is missing, and so is "
            f"{res.path('main', 'curves')} to fall back on (run `python -m "
            "legs_jax.sweep --experiment case_study`)"
        )
    curves = res.table(exp, "curves")
    present = [o for o in objects if (curves["object"] == o).any()]
    if not present:
        raise MissingResults(
            f"{res.path(exp, 'curves')} holds none of the case-study objects "
            f"({', '.join(objects)})"
        )
    sets = res.object_sets()
    plt = _plt()
    n = len(present)
    fig = plt.figure(figsize=(12.5, 2.85 * n + 1.2))
    gs = fig.add_gridspec(
        n,
        3,
        width_ratios=[0.75, 1.0, 1.75],
        hspace=0.45,
        wspace=0.28,
        left=0.03,
        right=0.985,
        top=1 - 0.95 / (2.85 * n + 1.2),
        bottom=0.75 / (2.85 * n + 1.2),
    )
    info: dict[str, Any] = {"experiment": exp, "objects": {}}
    handles = {}
    horizon = None
    for i, name in enumerate(present):
        set_ = sets.get(name, "")
        obj_info: dict[str, Any] = {"set": set_}
        # --- object picture
        ax0 = fig.add_subplot(gs[i, 0])
        drawn = _draw_object(ax0, data, set_, name, size=260)
        n_poses = _pose_count(data, res, set_, name)
        obj_info.update(poses=n_poses, notes=drawn["notes"])
        title = f"{name}\n{_set_label(set_)}"
        title += f", N = {n_poses} poses" if n_poses is not None else ""
        ax0.set_title(title, fontsize=9.5)
        # --- histogram
        ax1 = fig.add_subplot(gs[i, 1])
        resv = _reservoir(data, res, set_, name)
        if resv is None:
            _note(ax1, "no reservoir data\n(grasps.parquet and problem file missing)")
            ax1.set_axis_off()
        else:
            rob, prior, pose = resv
            bins = np.linspace(0.0, 1.0, 21)
            w = np.full(len(rob), 100.0 / max(len(rob), 1))
            ax1.hist(
                rob,
                bins=bins,
                weights=w,
                color="#4c72b0",
                alpha=0.85,
                label="ground truth p",
            )
            if prior is not None:
                ax1.hist(
                    prior,
                    bins=bins,
                    weights=w,
                    histtype="step",
                    color="#dd8452",
                    lw=1.4,
                    label="prior q (synthetic)",
                )
            ax1.set_yscale("log")
            ax1.set_xlim(0, 1)
            ax1.set_xlabel("grasp success probability")
            ax1.set_ylabel("grasps (%)")
            n_pose = len(np.unique(pose))
            ax1.set_title(
                f"trial 0 reservoir: {len(rob)} grasps, {n_pose} poses", fontsize=9
            )
            ax1.legend(loc="upper right", frameon=False, fontsize=7.5)
            obj_info.update(grasps=len(rob), good_fraction=float(np.mean(rob >= 0.5)))
        # --- learning curves
        ax2 = fig.add_subplot(gs[i, 2])
        lc = an.learning_curves(curves, name)
        finals = {}
        for (m, v), g in lc.groupby(["method", "variant"], sort=False):
            st = _style(m, v)
            x = g["step"].to_numpy(float)
            y = g["gap_mean"].to_numpy(float)
            se = np.nan_to_num(g["gap_se"].to_numpy(float))
            (h,) = ax2.plot(x, y, color=st["color"], ls=st["ls"], lw=st["lw"])
            ax2.fill_between(x, y - se, y + se, color=st["color"], alpha=0.15, lw=0)
            handles[(m, v)] = h
            finals[an.arm_label(m, v)] = float(y[-1])
            horizon = max(horizon or 0, int(x.max()))
        ax2.set_xlim(0, horizon)
        ax2.set_ylim(bottom=0)
        ax2.set_xlabel("step (grasp attempts)")
        ax2.set_ylabel("optimality gap Δ")
        ax2.grid(alpha=0.25)
        ax2.set_title(f"{name}: learning curves", fontsize=9)
        obj_info["final_gap"] = finals
        obj_info["curves"] = an.curve_summary(lc)
        info["objects"][name] = obj_info
    order = an.sort_arms(handles)
    fig.legend(
        [handles[a] for a in order],
        [an.arm_label(*a) for a in order],
        loc="upper center",
        ncol=min(4, len(order)),
        frameon=False,
        bbox_to_anchor=(0.5, 1.0),
    )
    fig.text(
        0.5,
        0.005,
        "Curves: mean over T × R runs, band ±1 standard error. "
        "The prior of every method is synthetic (a stand-in for GQ-CNN). "
        "Histogram y axis is logarithmic.",
        ha="center",
        va="bottom",
        fontsize=8,
        color="#444444",
    )
    missing = [o for o in objects if o not in present]
    if missing:
        info["missing"] = missing
    return _save(fig, out / "fig3_case_study.png"), info


# ======================================================================= Fig. 4
def _early_stopping_checks(res: Results) -> tuple[pd.DataFrame, str, int]:
    """LEGS checks on the Dex-Net set: the early_stopping experiment, else the
    LEGS rows of main restricted to that set."""
    if res.has("early_stopping", "checks"):
        exp = "early_stopping"
        checks = res.table(exp, "checks")
    elif res.has("main", "checks"):
        exp = "main"
        checks = res.table(exp, "checks")
        if "set" in checks.columns and (checks["set"] == "dexnet_adv").any():
            checks = checks[checks["set"] == "dexnet_adv"]
    else:
        raise MissingResults(
            f"{res.path('early_stopping', 'checks')} is missing, and so is "
            f"{res.path('main', 'checks')} to fall back on (run `python -m "
            "legs_jax.sweep --experiment early_stopping`)"
        )
    checks = an.select_arm(
        checks, experiments.get("early_stopping").CHECK_METHODS[0], ""
    )
    if checks.empty:
        raise MissingResults(f"{res.path(exp, 'checks')} has no LEGS checks")
    return checks, exp, res.horizon(exp)


def early_stopping_figure(res: Results, out: Path) -> tuple[Path, dict[str, Any]]:
    """Fig. 4: accuracy and mean stopping step against rho_min, for both lower
    bounds, with the overall accuracy and tightness beside the paper's."""
    checks, exp, horizon = _early_stopping_checks(res)
    rho = res.manifest(exp).get("extra", {}).get("rho_min") or DEFAULT_RHO
    summary = an.bound_summary(checks)
    per_obj = an.bound_summary(checks, by_object=True)
    sens = an.stopping_sensitivity(checks, rho, horizon)
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(12.5, 4.3))
    fig.subplots_adjust(left=0.06, right=0.99, top=0.78, bottom=0.27, wspace=0.3)
    styles = {
        "all": dict(color="#d62728", marker="o", ls="-"),
        "attempted": dict(color="#1f77b4", marker="s", ls="--"),
    }
    labels = {
        "all": r"$\hat p^*$ over all candidates (paper's bound)",
        "attempted": r"$\hat p^*$ over attempted grasps (variant)",
    }
    few = 10  # accuracy over fewer stopped runs than this is drawn hollow
    for b, g in sens.groupby("bound", sort=False):
        st = styles.get(b, {})
        kw = dict(ms=4, lw=1.5, label=labels.get(b, b), **st)
        axes[0].plot(g["rho_min"], 100 * g["accuracy"], **kw)
        thin = g[(g["n_stopped"] > 0) & (g["n_stopped"] < few)]
        axes[0].plot(
            thin["rho_min"],
            100 * thin["accuracy"],
            ls="none",
            marker=st.get("marker", "o"),
            ms=6,
            mfc="white",
            mec=st.get("color"),
        )
        axes[1].plot(g["rho_min"], g["mean_stop_step"], **kw)
        axes[2].plot(g["rho_min"], 100 * g["frac_stopped"], **kw)
    axes[0].axhline(
        95, color="#777777", lw=1.2, ls="-.", label=r"$1-\delta_{stop}$ = 95 %"
    )
    if (sens["n_stopped"].between(1, few - 1)).any():
        axes[0].plot(
            [], [], ls="none", marker="o", mfc="white", mec="#555555",
            label=f"fewer than {few} runs stopped",
        )  # fmt: skip
    axes[0].set_ylabel("accuracy of stopped runs (%)")
    axes[0].set_title(r"true performance $\geq \rho_{min}$ when stopped")
    acc = 100 * sens["accuracy"].to_numpy(float)
    lo = float(np.nanmin(acc)) if np.isfinite(acc).any() else 90.0
    axes[0].set_ylim(min(90.0, math.floor((lo - 1.0) / 5) * 5), 101)
    axes[1].axhline(
        horizon, color="#777777", lw=1.2, ls=":", label=f"horizon H = {horizon}"
    )
    axes[1].set_ylabel("mean steps before stopping")
    axes[1].set_title("exploration before stopping")
    axes[1].set_ylim(0, horizon * 1.05)
    axes[2].set_ylabel("runs stopped before H (%)")
    axes[2].set_title("runs that reach the threshold")
    axes[2].set_ylim(-2, 102)
    for ax in axes:
        ax.set_xlabel(r"stopping threshold $\rho_{min}$")
        ax.set_xlim(0, 1)
        ax.grid(alpha=0.25)
    h0, l0 = axes[0].get_legend_handles_labels()
    h1, l1 = axes[1].get_legend_handles_labels()
    fig.legend(
        h0 + h1[-1:],
        l0 + l1[-1:],
        loc="upper center",
        ncol=3,
        frameon=False,
        bbox_to_anchor=(0.5, 0.99),
    )
    lines = []
    paper = an.PAPER_EARLY_STOPPING
    check_steps = np.unique(checks["step"].to_numpy(np.int64))
    every = int(np.diff(check_steps).min()) if len(check_steps) > 1 else check_steps[0]
    n_obj = checks["object"].nunique()
    for _, r in summary.iterrows():
        tag = "paper's bound" if r["bound"] == "all" else "variant (attempted)"
        text = (
            f"{tag}: accuracy {100 * r['accuracy']:.1f} %, "
            f"tightness {100 * r['tightness']:.2f} %"
        )
        if r["bound"] == "all":
            text += (
                f"   (paper: {100 * paper['accuracy']:.1f} % and "
                f"{100 * paper['tightness']:.2f} %)"
            )
        lines.append(text)
    lines.append(
        f"Overall over {int(summary['n_checks'].max())} checks "
        f"(every {every} steps) of "
        f"{sens['n_runs'].max()} LEGS runs on {n_obj} objects; "
        "prior: synthetic stand-in for GQ-CNN."
    )
    fig.text(0.5, 0.02, "\n".join(lines), ha="center", va="bottom", fontsize=8.5)
    info = dict(
        experiment=exp,
        summary=summary,
        per_object=per_obj,
        sensitivity=sens,
        horizon=horizon,
        n_objects=n_obj,
    )
    return _save(fig, out / "fig4_early_stopping.png"), info


# ================================================================ active set
def active_set_figure(
    res: Results, data: ObjectData, out: Path, obj: str | None = ACTIVE_OBJECT
) -> tuple[Path, dict[str, Any]]:
    """The active set of one LEGS rollout over time (the paper's Fig. 1, bottom):
    the object with its first and last active set drawn as grasps, and the
    ground-truth robustness of every active-set member at every check."""
    act = res.table("case_study", "active_set")
    grasps = (
        res.table("case_study", "grasps") if res.has("case_study", "grasps") else None
    )
    if obj is None and len(act):
        first = an.first_legs_rollout(act)
        changed = first.groupby(["object", "pose"], sort=False)["grasp"].nunique()
        obj = str(changed.groupby(level=0, sort=False).max().idxmax())
    if not (act["object"] == obj).any():
        avail = list(dict.fromkeys(act["object"]))
        if not avail:
            raise MissingResults(f"{res.path('case_study', 'active_set')} has no rows")
        obj = avail[0]
    pose, members, summary = an.active_set_trace(act, obj, grasps=grasps)
    set_ = res.object_sets().get(obj, "")
    steps = summary["step"].to_numpy(int)
    first, last = int(steps.min()), int(steps.max())
    plt = _plt()
    from matplotlib import cm, colors
    from matplotlib.collections import LineCollection

    cmap = plt.get_cmap("RdYlGn")
    norm = colors.Normalize(0.0, 1.0)
    fig = plt.figure(figsize=(12.5, 4.6))
    gs = fig.add_gridspec(
        1,
        3,
        width_ratios=[1, 1, 1.9],
        left=0.01,
        right=0.93,
        top=0.8,
        bottom=0.13,
        wspace=0.12,
    )

    def overlay(step):
        ids = members.loc[members["step"] == step, "grasp"].to_numpy(int)

        def draw(pb, p, img, ax):
            from legs_jax import render

            valid = np.flatnonzero(pb.valid[0, p])
            rng = np.random.default_rng(0)
            back = rng.choice(valid, size=min(300, len(valid)), replace=False)
            for sel, bold in ((back, False), (ids[ids < pb.num_grasps], True)):
                if len(sel) == 0:
                    continue
                seg = render.grasp_segments(
                    pb.grasp_center[0, p, sel],
                    pb.grasp_axis[0, p, sel],
                    pb.grasp_width[0, p, sel],
                )
                uv, vis = img.project(seg.reshape(-1, 3))
                uv = uv.reshape(-1, 2, 2)
                vis = vis.reshape(-1, 2).all(axis=1)
                if bold:
                    rob = pb.robustness[0, p, sel]
                    order = np.argsort(rob, kind="stable")  # best drawn last
                    col = cmap(norm(rob[order]))
                    col[:, 3] = np.where(vis[order], 1.0, 0.35)
                    lw = 2.2 if len(sel) <= 20 else 1.5
                    ax.add_collection(LineCollection(uv[order], colors=col, lw=lw))
                else:
                    ax.add_collection(
                        LineCollection(uv, colors=(0.4, 0.4, 0.4, 0.25), lw=0.6)
                    )

        return draw

    info: dict[str, Any] = {"object": obj, "pose": pose, "first": first, "last": last}
    for j, step in enumerate((first, last)):
        ax = fig.add_subplot(gs[0, j])
        drawn = _draw_object(ax, data, set_, obj, pose=pose, grasps=overlay(step))
        info.setdefault("notes", []).extend(drawn["notes"])
        s = summary[summary["step"] == step].iloc[0]
        title = f"active set at step {step}\n{int(s['n_members'])} grasps"
        if j == 1 and "grasp" in members.columns:
            g0 = set(members.loc[members["step"] == first, "grasp"])
            g1 = set(members.loc[members["step"] == last, "grasp"])
            info["new_members"] = len(g1 - g0)
            title += f" ({len(g1 - g0)} new)"
        ax.set_title(title + f", best p = {s['best']:.2f}", fontsize=9)
    ax = fig.add_subplot(gs[0, 2])
    jitter = np.random.default_rng(0).uniform(-0.25, 0.25, len(members))
    dx = (steps[1] - steps[0]) if len(steps) > 1 else 100
    ax.scatter(
        members["step"] + jitter * dx,
        members["robustness"],
        c=members["robustness"],
        cmap=cmap,
        norm=norm,
        s=6,
        alpha=0.55,
        lw=0,
    )
    ax.plot(steps, summary["best"], color="#d62728", lw=2, label="best member")
    ax.plot(steps, summary["mean"], color="#333333", lw=1.5, ls="--", label="mean")
    if "p_star" in summary.columns:
        ax.axhline(
            float(summary["p_star"].iloc[0]),
            color="#000000",
            ls=":",
            lw=1.3,
            label="best grasp of the reservoir (p*)",
        )
    ax.set_xlabel("step (grasp attempts)")
    ax.set_ylabel("ground-truth success probability p")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlim(0, last + dx * 0.5)
    ax.grid(alpha=0.25)
    ax.legend(
        loc="lower center",
        bbox_to_anchor=(0.5, 1.0),
        ncol=3,
        frameon=False,
        title="ground-truth robustness of the active-set members at every check",
        title_fontsize=9,
    )
    cax = fig.add_axes([0.945, 0.13, 0.012, 0.67])
    fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax, label="p")
    k_text = "k"
    if res.has("case_study", "runs"):
        runs = res.table("case_study", "runs")
        shown = experiments.get("case_study").ACTIVE_SET_METHODS[0]
        ks = runs.loc[runs["method"] == shown, "k"].unique() if "k" in runs else []
        if len(ks) == 1:
            k_text = str(int(ks[0]))
    fig.suptitle(
        f"LEGS active set on {obj} ({_set_label(set_)}), pose {pose}, trial 0, "
        f"rollout 0 (initial set: top {k_text} by the synthetic prior)",
        fontsize=10,
    )
    info.update(
        best_first=float(summary["best"].iloc[0]),
        best_last=float(summary["best"].iloc[-1]),
        mean_first=float(summary["mean"].iloc[0]),
        mean_last=float(summary["mean"].iloc[-1]),
        p_star=float(summary["p_star"].iloc[0]) if "p_star" in summary else None,
    )
    return _save(fig, out / "fig1_active_set.png"), info


# ==================================================================== tables
def _write_csv(df: pd.DataFrame, path: Path) -> Path:
    rp.write_text(path, rp.to_csv(df))
    return path


def main_tables(res: Results, out: Path) -> tuple[list[Path], dict[str, Any]]:
    runs = res.table("main", "runs")
    gaps = an.object_gaps(runs)
    t1 = an.table_one(gaps)
    wins = an.win_counts(gaps)
    win = an.winners(gaps)
    files = []
    horizon = int(runs["horizon"].max()) if "horizon" in runs.columns else None
    files += rp.write_pair("table1", rp.table_one_table(t1, horizon), out)
    files += rp.write_pair("wins", rp.wins_table(wins), out)
    files += rp.write_pair("per_object", rp.per_object_table(gaps, win), out)
    files.append(_write_csv(t1, out / "table1.csv"))
    files.append(_write_csv(gaps, out / "per_object.csv"))
    files.append(_write_csv(wins, out / "wins.csv"))
    return files, dict(
        gaps=gaps, table1=t1, wins=wins, winners=win, runs=runs, horizon=horizon
    )


def early_stopping_tables(info: dict[str, Any], out: Path) -> list[Path]:
    files = []
    files += rp.write_pair(
        "early_stopping", rp.early_stopping_table(info["summary"]), out
    )
    files += rp.write_pair(
        "early_stopping_per_object",
        rp.early_stopping_per_object_table(info["per_object"]),
        out,
    )
    files += rp.write_pair(
        "sensitivity", rp.sensitivity_table(info["sensitivity"]), out
    )
    files.append(_write_csv(info["sensitivity"], out / "sensitivity.csv"))
    return files


def appendix_tables(
    res: Results, out: Path, experiment: str, param: str
) -> tuple[list[Path], dict[str, Any]]:
    method = experiments.get(experiment).ARMS[0][0]  # the one method of the sweep
    runs = an.select_arm(res.table(experiment, "runs"), method, "", vary=(param,))
    if runs.empty:
        raise MissingResults(f"{res.path(experiment, 'runs')} has no LEGS runs")
    table = an.sweep_table(runs, param)
    other = "delta" if param == "s" else "s"
    vals = runs[other].unique() if other in runs.columns else []
    fixed = float(vals[0]) if len(vals) == 1 else None
    horizon = int(runs["horizon"].max()) if "horizon" in runs.columns else None
    text = rp.appendix_table(table, param, fixed, horizon)
    files = rp.write_pair(experiment, text, out)
    files.append(_write_csv(table, out / f"{experiment}.csv"))
    return files, dict(table=table, fixed=fixed, horizon=horizon)


# ==================================================================== driver
def generate(
    results: str | Path = "results",
    out: str | Path | None = None,
    data: str | Path = "data",
    *,
    case_objects: Sequence[str] = CASE_OBJECTS,
    active_object: str | None = ACTIVE_OBJECT,
    progress: bool = True,
    debug: bool = False,
) -> tuple[list[Path], list[str]]:
    """Write every table, figure and the report that the results allow.

    Returns (files written, problems): each problem is one line naming what was
    missing and which output was skipped.
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
    tables_dir, figures_dir = out / "tables", out / "figures"
    objdata = ObjectData(data, res)
    written: list[Path] = []
    problems: list[str] = []
    ctx: dict[str, Any] = {"results": res, "out": out}

    def step_main():
        files, ctx["main"] = main_tables(res, tables_dir)
        written.extend(files)

    def step_fig3():
        path, ctx["case_study"] = case_study_figure(
            res, objdata, figures_dir, case_objects
        )
        written.append(path)

    def step_fig4():
        path, info = early_stopping_figure(res, figures_dir)
        ctx["early_stopping"] = info
        written.append(path)
        written.extend(early_stopping_tables(info, tables_dir))

    def step_prior():
        files, ctx["prior_strength"] = appendix_tables(
            res, tables_dir, "prior_strength", "s"
        )
        written.extend(files)

    def step_conf():
        files, ctx["confidence"] = appendix_tables(
            res, tables_dir, "confidence", "delta"
        )
        written.extend(files)

    def step_active():
        path, ctx["active_set"] = active_set_figure(
            res, objdata, figures_dir, active_object
        )
        written.append(path)

    def step_problem_model():
        ctx["problem_model"] = problem_model_context(results)

    steps = [
        ("Table I, wins, per-object gaps", step_main),
        ("problem model before and after", step_problem_model),
        ("Fig. 3 case study", step_fig3),
        ("Fig. 4 early stopping", step_fig4),
        ("appendix: prior strength", step_prior),
        ("appendix: confidence", step_conf),
        ("active-set evolution", step_active),
    ]
    from tqdm import tqdm

    bar = tqdm(steps, desc="figures", disable=not progress, leave=False)
    for label, fn in bar:
        bar.set_postfix_str(label)
        try:
            fn()
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
    ctx["problems"] = problems
    report_path = out / "REPORT.md"
    rp.write_text(report_path, rp.build_report(ctx))
    written.append(report_path)
    return written, problems


def _set_summary(path: Path) -> pd.DataFrame | None:
    """Per set: share of grasps with p >= 0.5, λ-weighted p*, corr(p, q) and the
    prior-only gaps, means over the objects of ``summary.csv`` (None if absent)."""
    if not path.is_file():
        return None
    d = pd.read_csv(path)
    return d.groupby("set").agg(
        objects=("object", "count"),
        frac_good=("frac_p_ge_0.5", "mean"),
        p_star=("p_star", "mean"),
        corr=("prior_truth_corr", "mean"),
        dexnet_gap=("dexnet_gap", "mean"),
        k100_ub_gap=("k100_ub_gap", "mean"),
    )


def problem_model_context(results: Path) -> dict[str, Any] | None:
    """The problem model now (``precompute/summary.csv``) and before it changed
    (``previous/``: copies of the earlier results, see its README), for the
    report's before/after section; None without ``previous/``."""
    prev = Path(results) / "previous"
    if not prev.is_dir():
        return None
    out: dict[str, Any] = {
        "sets_before": _set_summary(prev / "summary.csv"),
        "sets_after": _set_summary(Path(results) / "precompute" / "summary.csv"),
    }
    for name in ("table1", "wins", "early_stopping"):
        f = prev / f"{name}.csv"
        out[f"{name}_before"] = (
            pd.read_csv(f, keep_default_na=False) if f.is_file() else None
        )
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m legs_jax.figures",
        description=(
            "Regenerate the paper's tables and figures from saved sweep results "
            "(never reruns a sweep): Table I with win counts, per-object gaps, "
            "Fig. 3 case study, Fig. 4 early stopping, the two appendix tables, "
            "the active-set evolution of one LEGS rollout, and REPORT.md with "
            "every number beside the paper's. Outputs whose results are missing "
            "are skipped with a message naming the missing file (exit status 1)."
        ),
    )
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
        default=list(CASE_OBJECTS),
        metavar="NAME",
        help="objects of Fig. 3 (default: %(default)s)",
    )
    p.add_argument(
        "--active-object",
        default=ACTIVE_OBJECT,
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
