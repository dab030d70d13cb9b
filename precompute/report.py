"""``python -m precompute report``: what the built problems look like, per object and
per set, beside the paper's prior-only rows.

Writes, under ``--out`` (default: ``results/precompute``, the committed report,
when every catalogue object is built and none is named; otherwise
``runs/precompute-report`` under the current folder; a folder of committed files
other than the full report's needs ``--overwrite``):

- ``summary.csv``: one row per object: set, object, poses P, landing probabilities
  λ (largest first, ``;``-separated), valid grasps per pose (mean over trials), the
  fraction of valid grasps with p ≥ 0.5, p* per pose (mean over trials), the
  λ-weighted p*, the prior's kind (learned or synthetic), the prior–truth
  correlation (Pearson, over all valid grasps of all trials), the prior's ROC AUC
  for p ≥ 0.5, and the prior-only gaps of the Dex-Net row and the K=100 upper bound
  (mean over trials; :func:`precompute.analysis.prior_only_gaps`), and the poses
  that cannot be learned (``unlearnable_poses``:
  :func:`legs_jax.core.problem.unlearnable_poses`, ``;``-separated).
- ``unlearnable.md`` (when there are any): those poses, one sentence each (also
  printed).
- ``sets.csv`` and ``sets.md``: per set, those two gaps (mean ± standard error
  across objects) beside the paper's (Dex-Net set 0.56 / 0.08, EGAD 0.59 / 0.13),
  and whether each lies within ±0.05 of the paper's.
- ``figures/poses/<set>/<object>.png``: the object drawn in each stable pose with
  the five grasps of highest ground truth of trial 0 (coloured by p).
- ``figures/prior_reliability.png``: the prior's reliability diagram per set (mean p
  and share of p ≥ 0.5 per bin of q).
- ``figures/robustness_<set>.png``: a histogram of the ground-truth robustness of
  every valid grasp (all trials, all poses) per object, log scale (the paper's
  Fig. 3, middle row).

Problems of the user's own meshes (``<problems>/custom/*.npz``, and
``./problems/custom`` when ``--problems`` is not given) are reported too, as the
set ``custom`` (``--objects custom`` for those alone).

Each problem records its prior (learned or synthetic, ``meta["prior_kind"]``); the
object rows and the set table say which, and give its ROC AUC for p ≥ 0.5. The
synthetic prior is a calibrated stand-in for GQ-CNN, the learned one a small
network trained on generated objects (``precompute/prior_weights/MODEL_CARD.md``).
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from legs_jax.core.problem import (
    ProblemFileError,
    describe_unlearnable,
    load,
    unlearnable_poses,
)
from legs_jax.core.problem import prior_kind as of_meta
from legs_jax.report import render

from . import catalog
from ._cli import add_overwrite_arg, guard_out, subcommand_parser
from .analysis import PAPER, prior_only_gaps, prior_only_rows
from .build import problem_path, problems_dir
from .errors import PrecomputeError
from .mesh import load_mesh

__all__ = ["main", "object_row", "set_rows"]

GOOD = 0.5  # p at or above this counts as a good grasp
TOLERANCE = 0.05  # prior-only gaps within ±0.05 of the paper's
BEST_DRAWN = 5  # grasps drawn per pose
#: Default output folder of a report of every catalogue object (the committed one)
FULL_OUT = Path("results/precompute")
#: Default output folder of any other report (a user's own work)
PART_OUT = Path("runs/precompute-report")


def _fmt_list(values, digits: int) -> str:
    return ";".join(f"{v:.{digits}f}" for v in values)


def prior_kind(pb) -> str:
    """The prior a problem file carries (:func:`legs_jax.core.problem.prior_kind`)."""
    return of_meta(pb.meta)


def roc_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for the classes ``positive`` (ties
    count one half; NaN when a class is empty)."""
    from scipy.stats import rankdata

    positive = np.asarray(positive, bool)
    n1, n0 = int(positive.sum()), int((~positive).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    r = rankdata(np.asarray(score, np.float64))
    return float((r[positive].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def object_row(pb, set_name: str) -> dict:
    """Summary statistics of one problem (a :class:`legs_jax.core.problem.Problem`)."""
    P = int(pb.pose_valid.sum())
    valid = pb.valid[:, :P]
    p = np.where(valid, pb.robustness[:, :P], 0.0).astype(np.float64)
    q = pb.prior[:, :P].astype(np.float64)
    lam = pb.landing[:P].astype(np.float64)
    n_valid = valid.sum(axis=-1)  # [T, P]
    p_star = p.max(axis=-1)  # [T, P]
    pv, qv = p[valid], q[valid]
    corr = (
        float(np.corrcoef(pv, qv)[0, 1])
        if len(pv) > 1 and pv.std() > 0 and qv.std() > 0
        else float("nan")
    )
    g = prior_only_gaps(lam, pb.robustness[:, :P], pb.prior[:, :P], valid)
    return {
        "set": set_name,
        "object": pb.name,
        "prior": prior_kind(pb),
        "poses": P,
        "landing": _fmt_list(lam, 4),
        "valid_grasps_per_pose": _fmt_list(n_valid.mean(axis=0), 1),
        "valid_grasps": int(n_valid.sum()),
        "frac_p_ge_0.5": float((pv >= GOOD).mean()) if len(pv) else float("nan"),
        "p_star_per_pose": _fmt_list(p_star.mean(axis=0), 3),
        "p_star": float(g["p_star"].mean()),
        "prior_truth_corr": corr,
        "prior_auc": roc_auc(qv, pv >= GOOD),
        **{f"{m}_gap": float(g[rule].mean()) for m, rule in prior_only_rows().items()},
        "unlearnable_poses": ";".join(str(f["pose"]) for f in unlearnable_poses(pb)),
    }


def set_rows(rows: Sequence[dict]) -> list[dict]:
    """Per set: the two prior-only gaps, mean ± SE across objects, beside the
    paper's."""
    out = []
    for set_name in PAPER:
        sel = [r for r in rows if r["set"] == set_name]
        if not sel:
            continue
        entry = {"set": set_name, "objects": len(sel)}
        for j, col in enumerate(f"{m}_gap" for m in prior_only_rows()):
            x = np.array([r[col] for r in sel], np.float64)
            se = x.std(ddof=1) / math.sqrt(len(x)) if len(x) > 1 else float("nan")
            paper = PAPER[set_name][j]
            entry[col] = float(x.mean())
            entry[f"{col}_se"] = float(se)
            entry[f"{col}_paper"] = paper
            entry[f"{col}_within_0.05"] = bool(abs(x.mean() - paper) <= TOLERANCE)
        entry["prior_truth_corr"] = float(
            np.nanmean([r["prior_truth_corr"] for r in sel])
        )
        aucs = [r.get("prior_auc", np.nan) for r in sel]
        aucs = [x for x in aucs if not np.isnan(x)]  # NaN: one class only
        entry["prior_auc"] = float(np.mean(aucs)) if aucs else float("nan")
        entry["frac_p_ge_0.5"] = float(np.nanmean([r["frac_p_ge_0.5"] for r in sel]))
        entry["prior"] = "+".join(sorted({str(r.get("prior", "?")) for r in sel}))
        out.append(entry)
    return out


def _write_csv(rows: Sequence[dict], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow(
                {k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()}
            )
    tmp.replace(path)
    return path


def _sets_markdown(sets: Sequence[dict]) -> str:
    label = {"dexnet_adv": "Dex-Net adversarial", "egad_eval": "EGAD evaluation"}
    names = {
        "synthetic": "synthetic GQ-CNN stand-in",
        "learned": "learned GQ-CNN-style network",
    }
    kinds = sorted({k for s in sets for k in str(s.get("prior", "?")).split("+")})
    which = " and ".join(names.get(k, k) for k in kinds)
    lines = [
        f"# Prior-only rows of the built problems (prior: {which})",
        "",
        "Optimality gap at the prior's choice (Dex-Net row) and with the best of "
        "the 100 grasps of highest prior (K=100 upper bound), mean ± standard "
        "error across objects, beside the paper's Table I.",
        "",
        "| set | objects | Dex-Net gap | paper | K100 UB gap | paper | "
        "corr(p, q) | ROC AUC (p ≥ 0.5) | grasps with p ≥ 0.5 | prior |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    cols = [f"{m}_gap" for m in prior_only_rows()]
    for s in sets:
        mark = {True: "", False: " (outside ±0.05)"}
        gaps = "".join(
            f"{s[c]:.3f} ± {s[c + '_se']:.3f}{mark[s[c + '_within_0.05']]} | "
            f"{s[c + '_paper']:.2f} | "
            for c in cols
        )
        lines.append(
            f"| {label.get(s['set'], s['set'])} | {s['objects']} | "
            + gaps
            + f"{s['prior_truth_corr']:.2f} | {s.get('prior_auc', float('nan')):.2f} | "
            f"{100 * s['frac_p_ge_0.5']:.1f} % | {s.get('prior', '?')} |"
        )
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------- figures
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 8, "axes.titlesize": 8})
    return plt


def _grid(plt, n: int, max_cols: int, width: float, height: float, extra: float):
    """A figure with n panels in rows of at most ``max_cols``."""
    cols = min(n, max_cols)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(
        rows,
        cols,
        figsize=(width * cols, height * rows + extra),
        squeeze=False,
        layout="constrained",
    )
    return fig, axes, rows, cols


def _finish(plt, fig, title: str, fontsize: float, path: Path) -> Path:
    fig.suptitle(title, fontsize=fontsize)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90, metadata={"Software": None})
    plt.close(fig)
    return path


def _custom_mesh(pb, problem_file: Path):
    """The mesh of a problem of the user's own, as its build read it (metres),
    found from what the problem file records; None when it cannot be found."""
    import trimesh

    meta = pb.meta or {}
    cands = []
    if meta.get("mesh_file"):
        cands.append(Path(problem_file).resolve().parent / meta["mesh_file"])
    if meta.get("mesh_file_abs"):
        cands.append(Path(meta["mesh_file_abs"]))
    for c in cands:
        if c.is_file():
            try:
                m = load_mesh(
                    c,
                    meta.get("units", "m"),
                    meta.get("fit", "none"),
                    float(meta.get("scale", 1.0)),
                )
            except PrecomputeError:
                return None
            return trimesh.Trimesh(m.vertices, m.faces, process=False)
    return None


def pose_figure(pb, info, path: Path, panel: int = 150) -> Path:
    """The object in each stable pose with the best grasps of trial 0."""
    from matplotlib.collections import LineCollection

    fixed_scale = None
    if getattr(info, "set", None) == "custom":
        mesh = _custom_mesh(pb, info.path)
        if mesh is None:
            return None
        fixed_scale = 1.0  # read by precompute, in metres
    else:
        mesh = render.load_mesh(info.mesh_path)
    plt = _plt()
    P = int(pb.pose_valid.sum())
    fig, axes, rows, cols = _grid(plt, P, 6, 1.6, 1.75, 0.35)
    cmap = plt.get_cmap("viridis")
    for s in range(rows * cols):
        ax = axes[s // cols, s % cols]
        ax.set_axis_off()
        if s >= P:
            continue
        ok = np.flatnonzero(pb.valid[0, s])
        transform = pb.pose_transform[s]
        scale = fixed_scale or render.problem_scale(
            pb, mesh.vertices, transform, pb.grasp_center[0, s, ok]
        )
        verts = render.pose_vertices(mesh.vertices, transform, scale)
        img = render.render(verts, mesh.faces, size=panel)
        ax.imshow(img.image, interpolation="antialiased")
        ax.set_xlim(-0.5, img.size - 0.5)
        ax.set_ylim(img.size - 0.5, -0.5)
        if len(ok):
            rob = pb.robustness[0, s, ok]
            best = ok[np.argsort(-rob, kind="stable")[:BEST_DRAWN]][::-1]
            seg = render.grasp_segments(
                pb.grasp_center[0, s, best],
                pb.grasp_axis[0, s, best],
                pb.grasp_width[0, s, best],
            )
            uv, vis = img.project(seg.reshape(-1, 3))
            colors = cmap(pb.robustness[0, s, best])
            colors[:, 3] = np.where(vis.reshape(-1, 2).all(axis=1), 1.0, 0.4)
            ax.add_collection(LineCollection(uv.reshape(-1, 2, 2), colors=colors, lw=2))
        p_star = float(pb.robustness[0, s][pb.valid[0, s]].max()) if len(ok) else 0.0
        ax.set_title(
            f"pose {s}: λ={pb.landing[s]:.3f}\np*={p_star:.2f}, {len(ok)} grasps"
        )
    title = (
        f"{info.name} ({info.set}): {P} stable poses, 5 best grasps of trial 0 "
        "(colour: ground-truth p, 0 purple … 1 yellow)"
    )
    return _finish(plt, fig, title, 8, path)


def robustness_figure(
    objects: Sequence[tuple[str, np.ndarray]], set_name: str, path: Path
) -> Path:
    """Histogram of ground-truth robustness per object (all trials and poses):
    ``objects`` holds (name, robustness of every valid grasp) pairs."""
    plt = _plt()
    n = len(objects)
    fig, axes, rows, cols = _grid(plt, n, 7, 1.7, 1.35, 0.6)
    bins = np.linspace(0.0, 1.0, 21)
    for i in range(rows * cols):
        ax = axes[i // cols, i % cols]
        if i >= n:
            ax.set_axis_off()
            continue
        name, p = objects[i]
        ax.hist(p, bins=bins, color="#4c72b0", log=True)
        ax.set_title(name)
        ax.set_xlim(0, 1)
        ax.set_ylim(bottom=0.8)
        ax.tick_params(labelsize=6)
        if i % cols == 0:
            ax.set_ylabel("grasps", fontsize=7)
        if i // cols == rows - 1 or i + cols >= n:
            ax.set_xlabel("robustness p", fontsize=7)
    title = (
        f"{set_name}: ground-truth robustness of every reservoir grasp "
        "(all trials and poses, log scale)"
    )
    return _finish(plt, fig, title, 9, path)


RELIABILITY_BINS = 10


def reliability_counts(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """[bins, 4] per equal-width bin of q: grasps, Σq, Σp, grasps with p ≥ 0.5
    (sums, so that objects add up)."""
    q = np.asarray(q, np.float64)
    p = np.asarray(p, np.float64)
    k = np.minimum((q * RELIABILITY_BINS).astype(np.int64), RELIABILITY_BINS - 1)
    n = RELIABILITY_BINS
    return np.stack(
        [
            np.bincount(k, minlength=n).astype(np.float64),
            np.bincount(k, q, n),
            np.bincount(k, p, n),
            np.bincount(k, (p >= GOOD).astype(np.float64), n),
        ],
        axis=1,
    )


def reliability_figure(counts: dict, priors: dict, path: Path) -> Path:
    """Reliability diagram of the prior per set: mean p (solid) and share of
    p ≥ 0.5 (dashed) against mean q, per bin of q; ``counts``: set ->
    :func:`reliability_counts` summed over its objects; ``priors``: set -> kind."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(4.2, 4.0), layout="constrained")
    ax.plot([0, 1], [0, 1], color="0.7", lw=1)
    for set_name, c in counts.items():
        ok = c[:, 0] > 0
        mq = c[ok, 1] / c[ok, 0]
        (line,) = ax.plot(
            mq, c[ok, 2] / c[ok, 0], "o-", label=f"{set_name} ({priors[set_name]})"
        )
        ax.plot(mq, c[ok, 3] / c[ok, 0], "s--", color=line.get_color(), alpha=0.6)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("prior q (bin mean)")
    ax.set_ylabel("ground truth: mean p (solid), share p ≥ 0.5 (dashed)")
    ax.legend(fontsize=7, loc="upper left")
    return _finish(plt, fig, "Reliability of the prior on the evaluation sets", 9, path)


# ------------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    ap = subcommand_parser("report", __doc__)
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: results/precompute when every catalogue "
        "object is built and reported, the committed results; otherwise "
        "runs/precompute-report under the current folder)",
    )

    add_overwrite_arg(ap, "--out")
    ap.add_argument(
        "--objects",
        "--object",
        "--set",
        dest="objects",
        nargs="+",
        action="extend",
        metavar="NAME",
        help="objects or sets (default: all, and the problems of your own meshes); "
        "custom: those of your own meshes alone; --object and --set are the same",
    )
    ap.add_argument("--no-figures", action="store_true", help="tables only")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def _unlearnable_markdown(lines: Sequence[str]) -> str:
    return (
        "# Poses that cannot be learned\n\n"
        "No grasp of these poses can succeed in some trials, or a failed grasp "
        "never moves the object out of them: no method can learn there, and a "
        "rollout that lands in such a pose may stay stuck.\n\n"
        + "".join(f"- {line}\n" for line in lines)
    )


def _custom_problems(folders) -> list:
    """[(info, path)] of the problem files of the user's own meshes in
    ``folders`` (``<problems>/custom``), each once."""
    from types import SimpleNamespace

    out, seen = [], set()
    for folder in folders:
        for path in sorted(Path(folder).glob("*.npz")):
            key = path.resolve()
            if key in seen:
                continue
            seen.add(key)
            out.append((SimpleNamespace(name=path.stem, set="custom", path=path), path))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    root = a.problems if a.problems is not None else problems_dir()
    names = list(a.objects or [])
    want_custom = not names or "custom" in names
    names = [n for n in names if n != "custom"]
    if names:
        infos = catalog.resolve(names)
    else:
        infos = [] if a.objects else list(catalog.objects())
    found = [(i, problem_path(i, root)) for i in infos]
    missing = [i.name for i, p in found if not p.is_file()]
    found = [(i, p) for i, p in found if p.is_file()]
    custom = []
    if want_custom:
        folders = [Path(root) / "custom"]
        if a.problems is None:  # where python -m precompute --mesh writes
            folders.append(Path.cwd() / "problems" / "custom")
        custom = _custom_problems(folders)
        found += custom
    if not found:
        raise PrecomputeError(
            f"no problem files under {root}: build them with "
            "'python -m precompute --all' (or --mesh FILE, then report "
            "--problems problems)"
        )
    if missing and len(missing) < len(infos):
        print(f"{len(missing)} object(s) not built, left out: {' '.join(missing)}")
    full = not a.objects and not missing and not custom
    if a.out is None:
        a.out = FULL_OUT if full else PART_OUT
    if not full:
        # a part of the catalogue never replaces the committed full report

        guard_out(a.out, a.overwrite)

    from tqdm import tqdm

    rows, by_set, rel, kinds, unlearnable = [], {}, {}, {}, []
    bar = tqdm(found, desc="objects", unit="obj", disable=a.quiet)
    for info, path in bar:
        bar.set_postfix_str(info.name)
        try:
            pb = load(path)
        except ProblemFileError as e:
            raise PrecomputeError(str(e)) from None
        rows.append(object_row(pb, info.set))
        for line in describe_unlearnable(unlearnable_poses(pb)):
            unlearnable.append(f"{info.set}/{info.name}: {line}")
        # Only what the histogram needs, not the whole problem.
        by_set.setdefault(info.set, []).append((pb.name, pb.robustness[pb.valid]))
        c = reliability_counts(pb.prior[pb.valid], pb.robustness[pb.valid])
        rel[info.set] = rel.get(info.set, 0) + c
        kinds.setdefault(info.set, set()).add(prior_kind(pb))
        if not a.no_figures:
            pose_figure(
                pb, info, a.out / "figures" / "poses" / info.set / f"{info.name}.png"
            )
    written = [_write_csv(rows, a.out / "summary.csv")]
    sets = set_rows(rows)
    if sets:  # the catalogue's sets (none for meshes of the user's own alone)
        written.append(_write_csv(sets, a.out / "sets.csv"))
        md = a.out / "sets.md"
        md.write_text(_sets_markdown(sets))
        written.append(md)
    if not a.no_figures:
        for set_name, objects in by_set.items():
            written.append(
                robustness_figure(
                    objects, set_name, a.out / "figures" / f"robustness_{set_name}.png"
                )
            )
        priors = {k: "+".join(sorted(v)) for k, v in kinds.items()}
        written.append(
            reliability_figure(rel, priors, a.out / "figures" / "prior_reliability.png")
        )
    if unlearnable:
        md = a.out / "unlearnable.md"
        md.write_text(_unlearnable_markdown(unlearnable))
        written.append(md)
    if not a.quiet and sets:
        print(_sets_markdown(sets))
        for p in written:
            print(f"wrote {p}")
    if unlearnable:
        print(f"poses that cannot be learned ({len(unlearnable)}):")
        for line in unlearnable:
            print(f"  {line}")
    what = "the full catalogue" if full else f"{len(rows)} object(s)"
    print(f"report of {what} -> {a.out}")
    return 0
