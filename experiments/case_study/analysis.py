"""What the ``case_study`` experiment makes: Fig. 3 (object, robustness histogram and
learning curves of each object), the active set of one LEGS rollout (the paper's
Fig. 1, bottom), and their sections of the report.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.case_study.sweep import ACTIVE_SET_METHODS, OBJECTS
from experiments.main.tables import ARMS
from legs_jax.report import analysis as an
from legs_jax.report import render
from legs_jax.report.document import fmt, pct
from legs_jax.report.figures import (
    MissingResults,
    ObjectData,
    Results,
    Run,
    method_style,
    note_on_axes,
    pyplot,
    save_figure,
    set_label,
)


def _case_study_lines(info: Mapping, main: Mapping | None) -> list[str]:
    lines = [
        "| object | set | poses | grasps with p ≥ 0.5 | LEGS gap at H | lowest other "
        "gap at H | LEGS mean gap over the run | lowest other mean gap over the run "
        "| paper's reading |",
        "|:---|:---|---:|---:|---:|:---|---:|:---|:---|",
    ]
    paper_reading = {
        "climbing_hold": "LEGS converges faster",
        "C3": "LEGS converges faster",
        "F6": "LEGS does not beat every baseline",
        "turbine_housing": "LEGS does not beat every baseline",
    }
    for name, o in info["objects"].items():
        cs = o.get("curves")
        legs_final = legs_area = None
        best_final = best_area = "—"
        if cs is not None and len(cs):
            comp = cs[cs["method"].isin(ARMS.competitors) & (cs["variant"] == "")]
            legs = comp[comp["method"] == ARMS.proposed]
            rest = comp[comp["method"] != ARMS.proposed]
            if len(legs):
                legs_final = float(legs["final"].iloc[0])
                legs_area = float(legs["area"].iloc[0])
            if len(rest):
                f = rest.loc[rest["final"].idxmin()]
                a = rest.loc[rest["area"].idxmin()]
                best_final = f"{fmt(float(f['final']))} ({ARMS.label(f['method'])})"
                best_area = f"{fmt(float(a['area']))} ({ARMS.label(a['method'])})"
        good = o.get("good_fraction")
        set_ = o.get("set", "")
        lines.append(
            f"| {name} | {an.SET_LABELS.get(set_, set_)} | "
            f"{o.get('poses') if o.get('poses') is not None else 'n/a'} | "
            f"{pct(good) if good is not None else 'n/a'} | {fmt(legs_final)} | "
            f"{best_final} | {fmt(legs_area)} | {best_area} | "
            f"{paper_reading.get(name, '—')} |"
        )
    lines += [
        "",
        "The mean gap over the run is the area under the learning curve divided "
        'by H: lower means faster convergence. "Other" is every compared method '
        "but LEGS (Dex-Net, TQL, both BORGES, LEGS(-AS)); the upper bound is left "
        "out.",
        "",
    ]
    notes = [n for o in info["objects"].values() for n in o.get("notes", [])]
    if notes:
        lines += ["Drawing notes: " + "; ".join(dict.fromkeys(notes)) + ".", ""]
    if info.get("missing"):
        lines += [
            "Not in the results: " + ", ".join(info["missing"]) + ".",
            "",
        ]
    return lines


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
    ax.set_axis_off()
    info: dict[str, Any] = {"pose": pose, "notes": []}
    mesh, why_mesh = data.mesh(set_, name)
    pb, why_pb = data.problem(set_, name)
    if mesh is None:
        info["notes"].append(why_mesh)
        note_on_axes(ax, "no picture:\n" + _wrap_path(why_mesh))
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
        note_on_axes(ax, f"rendering failed:\n{e}")
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


def case_study_figure(
    res: Results,
    data: ObjectData,
    out: Path,
    objects: Sequence[str] = OBJECTS,
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
    plt = pyplot()
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
        title = f"{name}\n{set_label(set_)}"
        title += f", N = {n_poses} poses" if n_poses is not None else ""
        ax0.set_title(title, fontsize=9.5)
        # --- histogram
        ax1 = fig.add_subplot(gs[i, 1])
        resv = _reservoir(data, res, set_, name)
        if resv is None:
            note_on_axes(
                ax1, "no reservoir data\n(grasps.parquet and problem file missing)"
            )
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
                    label=f"prior q ({an.prior_kind(res)})",
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
        lc = an.learning_curves(curves, name, ARMS)
        finals = {}
        for (m, v), g in lc.groupby(["method", "variant"], sort=False):
            st = method_style(m, v, ARMS)
            x = g["step"].to_numpy(float)
            y = g["gap_mean"].to_numpy(float)
            se = np.nan_to_num(g["gap_se"].to_numpy(float))
            (h,) = ax2.plot(x, y, color=st["color"], ls=st["ls"], lw=st["lw"])
            ax2.fill_between(x, y - se, y + se, color=st["color"], alpha=0.15, lw=0)
            handles[(m, v)] = h
            finals[ARMS.label(m, v)] = float(y[-1])
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
    order = ARMS.sort(handles)
    fig.legend(
        [handles[a] for a in order],
        [ARMS.label(*a) for a in order],
        loc="upper center",
        ncol=min(4, len(order)),
        frameon=False,
        bbox_to_anchor=(0.5, 1.0),
    )
    fig.text(
        0.5,
        0.005,
        "Curves: mean over T × R runs, band ±1 standard error. "
        f"The prior of every method is {an.prior_kind(res)}. "
        "Histogram y axis is logarithmic.",
        ha="center",
        va="bottom",
        fontsize=8,
        color="#444444",
    )
    missing = [o for o in objects if o not in present]
    if missing:
        info["missing"] = missing
    return save_figure(fig, out / "fig3_case_study.png"), info


# None: the case-study object whose LEGS active set changes most (the most
# distinct members on one pose), which shows the pruning best.
ACTIVE_OBJECT: str | None = None


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
        first = an.first_rollout(act, ACTIVE_SET_METHODS[0])
        changed = first.groupby(["object", "pose"], sort=False)["grasp"].nunique()
        obj = str(changed.groupby(level=0, sort=False).max().idxmax())
    if not (act["object"] == obj).any():
        avail = list(dict.fromkeys(act["object"]))
        if not avail:
            raise MissingResults(f"{res.path('case_study', 'active_set')} has no rows")
        obj = avail[0]
    pose, members, summary = an.active_set_trace(
        act, obj, ACTIVE_SET_METHODS[0], grasps=grasps
    )
    set_ = res.object_sets().get(obj, "")
    steps = summary["step"].to_numpy(int)
    first, last = int(steps.min()), int(steps.max())
    plt = pyplot()
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
        shown = ACTIVE_SET_METHODS[0]
        ks = runs.loc[runs["method"] == shown, "k"].unique() if "k" in runs else []
        if len(ks) == 1:
            k_text = str(int(ks[0]))
    fig.suptitle(
        f"LEGS active set on {obj} ({set_label(set_)}), pose {pose}, trial 0, "
        f"rollout 0 (initial set: top {k_text} by the {an.prior_kind(res)} prior)",
        fontsize=10,
    )
    info.update(
        best_first=float(summary["best"].iloc[0]),
        best_last=float(summary["best"].iloc[-1]),
        mean_first=float(summary["mean"].iloc[0]),
        mean_last=float(summary["mean"].iloc[-1]),
        p_star=float(summary["p_star"].iloc[0]) if "p_star" in summary else None,
    )
    return save_figure(fig, out / "fig1_active_set.png"), info


# ====================================================================== steps
def _figure_step(run: Run) -> None:
    objects = run.options.get("case_objects") or OBJECTS
    path, run.ctx["case_study"] = case_study_figure(
        run.res, run.objects, run.figures, objects
    )
    run.written.append(path)


def _active_set_step(run: Run) -> None:
    path, run.ctx["active_set"] = active_set_figure(
        run.res, run.objects, run.figures, run.options.get("active_object")
    )
    run.written.append(path)


STEPS = (
    ("Fig. 3 case study", _figure_step),
    ("active-set evolution", _active_set_step),
)


# ==================================================================== report
def _case_study_section(ctx: Mapping) -> list[str]:
    L = ["## Fig. 3: case study", ""]
    cs = ctx.get("case_study")
    if cs:
        L += [
            "![Fig. 3: object, robustness histogram and learning curves of four "
            "objects](figures/fig3_case_study.png)",
            "",
            f"Learning curves from the `{cs['experiment']}` experiment. Paper: LEGS "
            "converges faster than the baselines on the climbing hold and C3, and "
            "does not beat every baseline on F6 and the turbine housing, where good "
            "grasps are abundant.",
            "",
        ]
        L += _case_study_lines(cs, ctx.get("main"))
    else:
        L += ["_Not available: the case-study results are missing._", ""]
    return L


def _active_set_section(ctx: Mapping) -> list[str]:
    L = ["## Active-set evolution of one LEGS rollout (Fig. 1, bottom)", ""]
    act = ctx.get("active_set")
    if act:
        L += [
            "![Active set of one LEGS rollout over time](figures/fig1_active_set.png)",
            "",
            f"{act['object']}, pose {act['pose']}, trial 0, rollout 0: the best "
            f"member of the active set goes from p = {fmt(act['best_first'], 2)} at "
            f"step {act['first']} to p = {fmt(act['best_last'], 2)} at step "
            f"{act['last']}, the mean member from {fmt(act['mean_first'], 2)} to "
            f"{fmt(act['mean_last'], 2)}"
            + (
                f"; the best grasp of the pose's reservoir has p* = "
                f"{fmt(act['p_star'], 2)}."
                if act.get("p_star") is not None
                else "."
            ),
            "",
        ]
        if act.get("notes"):
            L += ["Drawing notes: " + "; ".join(dict.fromkeys(act["notes"])) + ".", ""]
    else:
        L += ["_Not available: the case-study active sets are missing._", ""]
    return L


SECTIONS = ((30, _case_study_section), (60, _active_set_section))
