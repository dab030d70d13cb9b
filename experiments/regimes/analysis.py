"""What the ``regimes`` experiment makes: the features and final gaps of every
generated problem (``tables/regimes.md``, ``.tex``, ``.csv``), the same features
of the real objects with their measured differences from ``main``
(``tables/regimes_real.csv``), the maps (``figures/regimes_map.png``: LEGS −
BORGES (K=100), LEGS − BORGES (K=2000), LEGS − Bayes-UCB (K=100) over p-shape ×
prior C-index, real objects overlaid; ``figures/regimes_side.png``: the side axes,
the LEGS settings and the horizon) and the report's section, every sentence of
which is computed from these numbers.

Why one file: the numbers, the tables, the two maps and the report's section are one
chain over the frame that :func:`summarise` makes, each section a few short
functions; kept together, one number can be followed from the frame to the sentence
that states it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from experiments.regimes import sweep as decl
from legs_jax import families
from legs_jax.core import problem as problem_mod
from legs_jax.report.analysis import oracle_methods
from legs_jax.report.document import Num, Table, fmt, to_markdown, write_pair
from legs_jax.report.figures import MissingResults, Run, pyplot, save_figure, write_csv

NAME = decl.NAME
PROPOSED = "legs"
# The comparisons of the maps: (column, arm it is compared with, label).
COMPARED = (
    ("borges_100", "BORGES (K=100)"),
    ("borges_2000", "BORGES (K=2000)"),
    ("bayes_ucb_100", "Bayes-UCB (K=100)"),
)
# Features of the map's axes and of the table.
FEATURES = (
    ("mean_over_best", "mean p / p*"),
    ("count_near", "grasps ≥ p* − 0.05"),
    ("auc", "prior C-index"),
    ("calibration", "mean q − mean p"),
    ("effective_poses", "1/Σλ²"),
    ("attempts_per_active", "attempts per active grasp"),
)
# Features of a real object are measured on its first trials (the C-index on 400
# random grasps of each pose and trial).
REAL_TRIALS = 3
# "Significant": a difference beyond this many standard errors.
Z = 2.0


# ==================================================================== numbers
def _arm_names(runs: pd.DataFrame) -> pd.Series:
    """One label per arm and grid point: method[.variant][ γ=…] (the grid's own
    hyperparameters, those that vary within the arm, are named)."""
    label = runs["method"] + np.where(runs["variant"] != "", "." + runs["variant"], "")
    label = pd.Series(label, index=runs.index)
    for _, idx in runs.groupby(["method", "variant"]).groups.items():
        part = runs.loc[idx]
        vary = [
            c
            for c in ("s", "prior_offset", "delta", "gamma", "k", "n")
            if c in part.columns and part[c].nunique() > 1
        ]
        for c in vary:
            label.loc[idx] = label.loc[idx] + f" {c}=" + part[c].map(lambda v: f"{v:g}")
    return label


def gaps(runs: pd.DataFrame) -> pd.DataFrame:
    """Final gap per (object, arm): mean, standard error, runs."""
    df = runs.assign(arm=_arm_names(runs))
    g = df.groupby(["object", "arm"])["final_gap"]
    out = pd.DataFrame({"mean": g.mean(), "se": g.std(ddof=1) / np.sqrt(g.count())})
    out["n"] = g.count()
    return out.reset_index()


def differences(g: pd.DataFrame, a: str, b: str) -> pd.DataFrame:
    """a − b per object, with the standard error of a difference of independent
    means (conservative: rollouts of two methods share their environment keys)."""
    m = g.pivot(index="object", columns="arm", values="mean")
    s = g.pivot(index="object", columns="arm", values="se")
    if a not in m or b not in m:
        return pd.DataFrame(columns=["diff", "se"])
    return pd.DataFrame(
        {"diff": m[a] - m[b], "se": np.sqrt(s[a] ** 2 + s[b] ** 2)}
    ).dropna()


def _family_of(name: str) -> dict[str, Any] | None:
    return dict(dict(decl.GENERATED).get(name) or {}) or None


def generated_features(run: Run, names: Sequence[str]) -> pd.DataFrame:
    """Features of the generated problems: from the files the sweep ran (the
    objects table), else regenerated from the declaration."""
    files = {}
    if run.res.has(NAME, "objects"):
        obj = run.res.table(NAME, "objects")
        if "problem_file" in obj.columns:
            files = dict(zip(obj["object"], obj["problem_file"], strict=True))
    rows = []
    for n in names:
        pb = None
        path = files.get(n)
        if path:
            try:
                pb = problem_mod.load(path)
            except Exception:  # noqa: BLE001 - regenerate instead
                pb = None
        fam = _family_of(n)
        if pb is None and fam is not None:
            pb = families.make_problem(name=n, **fam)
        if pb is None:
            continue
        f = families.features(pb, horizon=run.res.horizon(NAME))
        fam = fam or dict(pb.meta.get("family") or {})
        base = decl.BASE
        f.update(
            object=n,
            shape=fam.get("shape", ""),
            auc_level=float(fam.get("auc", np.nan)),
            family_calibration=fam.get("calibration", ""),
            excellent=float(fam.get("excellent", np.nan)),
            on_map=(
                fam.get("calibration") == base["calibration"]
                and fam.get("excellent") == base["excellent"]
                and fam.get("effective_poses") == base["effective_poses"]
            ),
        )
        rows.append(f)
    return pd.DataFrame(rows)


def real_objects(run: Run) -> tuple[pd.DataFrame | None, str]:
    """Features of main's objects with their LEGS − X differences there, or None
    and the reason."""
    if not run.res.has("main", "runs"):
        return None, f"{run.res.path('main', 'runs')} is missing"
    runs = run.res.table("main", "runs")
    runs = runs[runs["variant"] == ""]
    g = gaps(runs)
    diffs = {b: differences(g, PROPOSED, b) for b, _ in COMPARED}
    horizon = run.res.horizon("main")
    rows, missing = [], []
    pairs = runs[["object", "set"]].drop_duplicates()
    for name, set_ in zip(pairs["object"], pairs["set"], strict=True):
        pb, why = run.objects.problem(set_, name)
        if pb is None:
            missing.append(f"{name} ({why})")
            continue
        f = families.features(pb, horizon=horizon, max_trials=REAL_TRIALS)
        f.update({"object": name, "set": set_})
        for b, _ in COMPARED:
            d = diffs[b]
            f[f"diff_{b}"] = float(d["diff"].get(name, np.nan))
            f[f"se_{b}"] = float(d["se"].get(name, np.nan))
        rows.append(f)
    if not rows:
        return None, "no problem file of main's objects: " + "; ".join(missing[:3])
    note = f"{len(missing)} object(s) without a problem file" if missing else ""
    return pd.DataFrame(rows), note


def summarise(run: Run) -> dict[str, Any]:
    """Everything the tables, figures and report section use."""
    runs = run.res.table(NAME, "runs")
    if runs.empty:
        raise MissingResults(f"{run.res.path(NAME, 'runs')} has no runs")
    g = gaps(runs)
    names = list(dict.fromkeys(runs["object"]))
    feats = generated_features(run, names).set_index("object")
    table = feats.copy()
    for arm, sub in g.groupby("arm"):
        table[f"gap_{arm}"] = sub.set_index("object")["mean"]
        table[f"se_{arm}"] = sub.set_index("object")["se"]
    for b, _ in COMPARED:
        d = differences(g, PROPOSED, b)
        table[f"diff_{b}"] = d["diff"]
        table[f"dse_{b}"] = d["se"]
    out: dict[str, Any] = {"table": table, "gaps": g, "arms": sorted(g["arm"].unique())}
    # The horizon: gaps of LEGS and the compared arms at the declared horizons.
    if run.res.has(NAME, "curves"):
        cur = run.res.table(NAME, "curves")
        cur = cur[cur["variant"] == ""]
        hz = [h for h in decl.HORIZONS if h in set(cur["step"])]
        rows = []
        for h in hz:
            at = cur[cur["step"] == h].pivot_table(
                index="object", columns="method", values="gap_mean"
            )
            row = {"horizon": h}
            for b, _ in COMPARED:
                if PROPOSED in at and b in at:
                    row[b] = float((at[PROPOSED] - at[b]).mean())
            rows.append(row)
        out["horizons"] = pd.DataFrame(rows)
    real, why = real_objects(run)
    if real is not None and not why:
        why = _main_source_note(run)
    out["real"], out["real_note"] = real, why
    return out


def _main_source_note(run: Run) -> str:
    """A caveat when main's results were not made from the problem files whose
    features place the real objects (the shipped set)."""
    try:
        files = run.res.manifest("main").get("problem_files") or {}
    except Exception:  # noqa: BLE001 - no manifest: nothing to say
        return ""
    sources = {str(f.get("source", "built")) for f in files.values()}
    if not files or sources == {"shipped"}:
        return ""
    return (
        "their LEGS − BORGES (K=100) comes from `main`'s results, made from "
        "problem files built on a machine, not the shipped set; the features "
        "are measured on the shipped problem set, and the two agree once `main` "
        "is recomputed on it"
    )


# ===================================================================== tables
def _num(x: float, se: float = float("nan")) -> Num:
    return Num(float(x), float(se))


def regimes_table(s: Mapping[str, Any]) -> Table:
    t = s["table"]
    rows = []
    for name, r in t.iterrows():
        row: list = [name]
        row += [fmt(r[c], 2) for c, _ in FEATURES]
        row.append(_num(r.get(f"gap_{PROPOSED}", np.nan), r.get(f"se_{PROPOSED}")))
        row += [
            _num(r.get(f"diff_{b}", np.nan), r.get(f"dse_{b}")) for b, _ in COMPARED
        ]
        rows.append(row)
    return Table(
        header=[
            "problem",
            *[lbl for _, lbl in FEATURES],
            "LEGS gap",
            *[f"LEGS − {lbl}" for _, lbl in COMPARED],
        ],
        rows=rows,
        align="l" + "c" * (len(FEATURES) + 1 + len(COMPARED)),
        caption="Generated problems: measured features and LEGS's final gap against "
        "the other methods (mean ± SE over T × R runs; negative: LEGS lower)",
        label="tab:regimes",
    )


def settings_table(s: Mapping[str, Any]) -> Table | None:
    """Final gap of every LEGS setting, averaged over the generated problems, and
    on how many problems each is significantly below / above the default."""
    g = s["gaps"]
    m = g.pivot(index="object", columns="arm", values="mean")
    se = g.pivot(index="object", columns="arm", values="se")
    legs = [a for a in m.columns if a == PROPOSED or a.startswith(PROPOSED + ".")]
    if PROPOSED not in m or len(legs) < 2:
        return None
    rows = []
    for a in [PROPOSED, *[x for x in legs if x != PROPOSED], *[b for b, _ in COMPARED]]:
        if a not in m:
            continue
        d = m[a] - m[PROPOSED]
        dse = np.sqrt(se[a] ** 2 + se[PROPOSED] ** 2)
        better = int((d < -Z * dse).sum()) if a != PROPOSED else 0
        worse = int((d > Z * dse).sum()) if a != PROPOSED else 0
        rows.append(
            [
                a,
                Num(float(m[a].mean()), float(np.sqrt((se[a] ** 2).sum()) / len(se))),
                f"{better} / {worse}" if a != PROPOSED else "–",
            ]
        )
    return Table(
        header=["arm", "mean final gap", "problems below / above LEGS (2 SE)"],
        rows=rows,
        align="lcc",
        caption="LEGS's settings against its default, over the generated problems",
        label="tab:regimes-settings",
    )


# ==================================================================== figures
def _levels(t: pd.DataFrame) -> tuple[list[str], list[float], np.ndarray, np.ndarray]:
    """The main map's shapes and AUC levels, and their measured feature values."""
    main = t[t["on_map"]]
    shapes = [x for x in decl.SHAPES if x in set(main["shape"])]
    aucs = [a for a in decl.AUCS if np.isclose(main["auc_level"], a).any()]
    xs = np.array([main[main["shape"] == x]["mean_over_best"].mean() for x in shapes])
    ys = np.array([main[np.isclose(main["auc_level"], a)]["auc"].mean() for a in aucs])
    return shapes, aucs, xs, ys


def _place(values: np.ndarray, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell coordinates of measured feature values (linear between the levels'
    measured values; clipped outside them, with a flag)."""
    order = np.argsort(levels)
    pos = np.interp(values, levels[order], np.arange(len(levels))[order])
    out = (values < levels.min()) | (values > levels.max())
    return pos, out


def _map_axes(ax, shapes: Sequence[str], xs: np.ndarray, ys: np.ndarray) -> None:
    """The map's axes: the p-distribution shapes (with their measured mean p / p*)
    across, the prior's C-index up."""
    ax.set_xticks(range(len(shapes)))
    ax.set_xticklabels([f"{x}\n{v:.2f}" for x, v in zip(shapes, xs, strict=True)])
    ax.set_yticks(range(len(ys)))
    ax.set_yticklabels([f"{v:.2f}" for v in ys])
    ax.set_xlabel("p distribution (mean p / p*)")
    ax.set_ylabel("prior C-index")


def map_figure(s: Mapping[str, Any], path) -> Any:
    plt = pyplot()
    t = s["table"]
    shapes, aucs, xs, ys = _levels(t)
    real = s.get("real")
    fig, axes = plt.subplots(1, len(COMPARED), figsize=(4.2 * len(COMPARED), 4.0))
    diffs = [t[f"diff_{b}"] for b, _ in COMPARED if f"diff_{b}" in t]
    lim = max([float(np.nanmax(np.abs(d))) for d in diffs] + [0.01])
    if real is not None:
        for b, _ in COMPARED:
            v = real[f"diff_{b}"].to_numpy()
            if np.isfinite(v).any():
                lim = max(lim, float(np.nanmax(np.abs(v))))
    cmap = plt.get_cmap("RdBu_r")
    for ax, (b, lbl) in zip(np.atleast_1d(axes), COMPARED, strict=True):
        grid = np.full((len(aucs), len(shapes)), np.nan)
        for _, r in t.iterrows():
            if r["shape"] in shapes and np.isfinite(r["auc_level"]):
                ok = bool(r["on_map"])
                hit = [i for i, a in enumerate(aucs) if np.isclose(a, r["auc_level"])]
                if ok and hit and f"diff_{b}" in t:
                    grid[hit[0], shapes.index(r["shape"])] = r[f"diff_{b}"]
        im = ax.imshow(
            grid, origin="lower", cmap=cmap, vmin=-lim, vmax=lim, aspect="auto"
        )
        for i in range(len(aucs)):
            for j in range(len(shapes)):
                if np.isfinite(grid[i, j]):
                    ax.text(
                        j,
                        i,
                        f"{grid[i, j]:+.3f}",
                        ha="center",
                        va="center",
                        fontsize=7.5,
                    )
        _map_axes(ax, shapes, xs, ys)
        ax.set_title(f"LEGS − {lbl}")
        if real is not None and len(xs) > 1 and len(ys) > 1:
            px, xout = _place(real["mean_over_best"].to_numpy(), xs)
            py, yout = _place(real["auc"].to_numpy(), ys)
            c = real[f"diff_{b}"].to_numpy()
            inside = ~(xout | yout)
            for mask, marker in ((inside, "o"), (~inside, "^")):
                if mask.any():
                    ax.scatter(
                        px[mask],
                        py[mask],
                        c=c[mask],
                        cmap=cmap,
                        vmin=-lim,
                        vmax=lim,
                        marker=marker,
                        s=22,
                        edgecolors="black",
                        linewidths=0.6,
                        zorder=3,
                    )
        fig.colorbar(im, ax=ax, shrink=0.8, label="final gap difference")
    note = "cells: generated problems; markers: the real objects (main), placed by "
    note += "their measured features and coloured by their own difference"
    note += " (triangles: outside the map, drawn at its edge)"
    fig.suptitle(note, fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def side_figure(s: Mapping[str, Any], path) -> Any:
    plt = pyplot()
    t = s["table"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11.0, 0.28 * len(t) + 1.6))
    y = np.arange(len(t))
    h = 0.8 / len(COMPARED)
    for i, (b, lbl) in enumerate(COMPARED):
        if f"diff_{b}" not in t:
            continue
        a1.barh(
            y + (i - 1) * h,
            t[f"diff_{b}"],
            height=h,
            xerr=Z * t[f"dse_{b}"],
            label=f"LEGS − {lbl}",
            error_kw=dict(lw=0.6),
        )
    a1.axvline(0, color="black", lw=0.6)
    a1.set_yticks(y)
    a1.set_yticklabels(t.index, fontsize=7)
    a1.invert_yaxis()
    a1.set_xlabel("final gap difference (± 2 SE)")
    a1.legend(loc="lower right")
    legs = [c for c in t.columns if c.startswith(f"gap_{PROPOSED}")]
    for c in legs:
        a2.plot(t[c].to_numpy(), y, marker="o", ms=3, lw=0.8, label=c[4:])
    for b, lbl in COMPARED[:2]:
        if f"gap_{b}" in t:
            a2.plot(t[f"gap_{b}"].to_numpy(), y, marker="s", ms=3, lw=0, label=lbl)
    a2.set_yticks(y)
    a2.set_yticklabels([])
    a2.invert_yaxis()
    a2.set_xlabel("final gap")
    a2.legend(loc="lower right", fontsize=7)
    a2.set_title("LEGS's settings")
    fig.tight_layout()
    return save_figure(fig, path)


# ====================================================================== steps
def _step(run: Run) -> None:
    s = summarise(run)
    run.ctx[NAME] = s
    run.written += write_pair("regimes", regimes_table(s), run.tables)
    run.written.append(write_csv(s["table"].reset_index(), run.tables / "regimes.csv"))
    st = settings_table(s)
    if st is not None:
        run.written += write_pair("regimes_settings", st, run.tables)
    if s["real"] is not None:
        run.written.append(write_csv(s["real"], run.tables / "regimes_real.csv"))
    run.written.append(map_figure(s, run.figures / "regimes_map.png"))
    run.written.append(side_figure(s, run.figures / "regimes_side.png"))
    if versus_best(s["table"]) is not None:
        run.written.append(ours_figure(s, run.figures / "regimes_ours.png"))


STEPS = (("regimes: when does LEGS win", _step),)


# ===================================================================== report
def _sig(d: float, se: float) -> int:
    """-1: significantly below 0, 1: above, 0: neither."""
    if not (math.isfinite(d) and math.isfinite(se)):
        return 0
    return -1 if d < -Z * se else (1 if d > Z * se else 0)


def _where(t: pd.DataFrame, b: str) -> tuple[list[str], list[str]]:
    col, se = f"diff_{b}", f"dse_{b}"
    if col not in t:
        return [], []
    s = [_sig(d, e) for d, e in zip(t[col], t[se], strict=True)]
    below = [n for n, x in zip(t.index, s, strict=True) if x < 0]
    above = [n for n, x in zip(t.index, s, strict=True) if x > 0]
    return below, above


def _names(xs: Sequence[str], limit: int = 8) -> str:
    if not xs:
        return "none"
    more = f" and {len(xs) - limit} more" if len(xs) > limit else ""
    return ", ".join(f"`{x}`" for x in xs[:limit]) + more


def _paper_order(t: pd.DataFrame) -> list[str]:
    """Problems where LEGS is significantly below BORGES (K=100) and not
    significantly above BORGES (K=2000)."""
    if "diff_borges_100" not in t or "diff_borges_2000" not in t:
        return []
    out = []
    for n, r in t.iterrows():
        if _sig(r["diff_borges_100"], r["dse_borges_100"]) < 0 and (
            _sig(r["diff_borges_2000"], r["dse_borges_2000"]) <= 0
        ):
            out.append(n)
    return out


def _real_lines(s: Mapping[str, Any]) -> list[str]:
    real = s.get("real")
    if real is None:
        return [
            f"- The real objects are not placed on the map: {s.get('real_note')}.",
        ]
    t = s["table"]
    q = real[[c for c, _ in FEATURES]].median()
    lo, hi = real["mean_over_best"].min(), real["mean_over_best"].max()
    d = real["diff_borges_100"]
    line = (
        f"- The {len(real)} real objects (features of their first {REAL_TRIALS} "
        f"trials; medians): mean p / p* {fmt(q['mean_over_best'], 2)} (from "
        f"{fmt(lo, 2)} to {fmt(hi, 2)}; the map's shapes span "
        f"{fmt(t['mean_over_best'].min(), 2)} to {fmt(t['mean_over_best'].max(), 2)}), "
        f"{fmt(q['count_near'], 1)} grasps within 0.05 of p*, prior C-index "
        f"{fmt(q['auc'], 2)}, calibration bias {fmt(q['calibration'], 3)}, "
        f"{fmt(q['effective_poses'], 1)} effective poses and "
        f"{fmt(q['attempts_per_active'], 1)} attempts per active grasp. Their own "
        f"LEGS − BORGES (K=100) in `main` has median {fmt(float(d.median()))} "
        f"(mean {fmt(float(d.mean()))}; {int((d < 0).sum())} of {int(d.notna().sum())} "
        "objects below 0)."
    )
    nearest = _nearest_cell(s)
    if nearest:
        line += " " + nearest
    out = [line]
    if s.get("real_note"):
        out.append(f"  ({s['real_note']}.)")
    return out


def _nearest_cell(s: Mapping[str, Any]) -> str:
    """The generated problem nearest the real objects' median features."""
    real, t = s.get("real"), s["table"]
    if real is None or "diff_borges_100" not in t:
        return ""
    cols = ["mean_over_best", "auc"]
    med = real[cols].median()
    main = t[t["on_map"]]
    dist = ((main[cols] - med) ** 2).sum(axis=1)
    if dist.empty:
        return ""
    n = dist.idxmin()
    r = t.loc[n]
    return (
        f"The generated problem nearest their median (mean p / p*, C-index) is "
        f"`{n}`, where LEGS − BORGES (K=100) is {fmt(r['diff_borges_100'])} ± "
        f"{fmt(r['dse_borges_100'])} and LEGS − BORGES (K=2000) "
        f"{fmt(r.get('diff_borges_2000', np.nan))} ± "
        f"{fmt(r.get('dse_borges_2000', np.nan))}."
    )


def _section(ctx: Mapping) -> list[str]:
    L = ["## When does LEGS win? A map of regimes", ""]
    s = ctx.get(NAME)
    if not s:
        return L + ["_Not available: the `regimes` results are missing._", ""]
    t = s["table"]
    L += [
        "The paper closes by asking how the prior's quality and the distribution of "
        "grasp success probabilities affect LEGS. `experiments/regimes` answers it on "
        f"{len(t)} generated problems (`legs_jax.families`, seeded) whose properties "
        "are set one at a time, runs every method with its defaults and LEGS with "
        "other settings on them, and places the real objects of `main` on the same "
        "map by the same measured features. Nothing in it is tuned: the problems are "
        "declared in `experiments/regimes/sweep.py` and every sentence below is "
        "computed from the results.",
        "",
        "![LEGS against the other methods over p-distribution shape × prior "
        "C-index](figures/regimes_map.png)",
        "",
    ]
    lines = []
    for b, lbl in COMPARED:
        col = f"diff_{b}"
        if col not in t:
            continue
        below, above = _where(t, b)
        i_min, i_max = t[col].idxmin(), t[col].idxmax()
        lines.append(
            f"- LEGS − {lbl}: from {fmt(t.loc[i_min, col])} (`{i_min}`) to "
            f"{fmt(t.loc[i_max, col])} (`{i_max}`); LEGS is lower by more than "
            f"{Z:g} SE on {len(below)} of {len(t)} problems ({_names(below)}) and "
            f"higher on {len(above)} ({_names(above)})."
        )
    L += lines
    paper = _paper_order(t)
    if paper:
        L.append(
            "- The paper's ordering (LEGS below BORGES (K=100) by more than "
            f"{Z:g} SE, and not above BORGES (K=2000) by more than {Z:g} SE) "
            f"appears on {len(paper)} problem(s): {_names(paper)}."
        )
    else:
        L.append(
            "- The paper's ordering (LEGS below BORGES (K=100) by more than "
            f"{Z:g} SE, and not above BORGES (K=2000) by more than {Z:g} SE) appears "
            "on none of the explored problems."
        )
    L += _ours_lines(t)
    L += _axis_lines(t)
    st = settings_table(s)
    if st is not None:
        L += ["", to_markdown(st)]
    hz = s.get("horizons")
    if hz is not None and len(hz) and "borges_100" in hz:
        parts = [f"{int(r.horizon)}: {fmt(r.borges_100)}" for r in hz.itertuples()]
        L.append(
            "- The horizon: LEGS − BORGES (K=100), averaged over the problems, at H = "
            + ", ".join(parts)
            + "."
        )
    L += _real_lines(s)
    L += [
        "",
        "![Every generated problem: the differences (± 2 SE) and LEGS's settings]"
        "(figures/regimes_side.png)",
        "",
        "Per problem: `tables/regimes.md` (features, LEGS's gap, the differences); "
        "the real objects' features: `tables/regimes_real.csv`. The C-index is the "
        "probability that q ranks the better of two grasps of a pose higher (the "
        'ROC AUC of q for "the better of the pair"); SE of a difference: of two '
        "independent means.",
        "",
    ]
    return L


def versus_best(t: pd.DataFrame) -> pd.DataFrame | None:
    """Our method on every problem against the lowest other arm there (the oracle
    excluded): ``best`` (that arm), ``diff`` (ours − it) and ``se`` (of two
    independent means); None where our method did not run."""
    ours = decl.OURS
    if f"gap_{ours}" not in t:
        return None
    others = [
        c[4:]
        for c in t.columns
        if c.startswith("gap_") and c[4:] != ours and c[4:] not in oracle_methods()
    ]
    if not others:
        return None
    best = t[[f"gap_{a}" for a in others]].idxmin(axis=1).str[4:]
    bgap = pd.Series([t.loc[o, f"gap_{a}"] for o, a in best.items()], t.index)
    bse = pd.Series([t.loc[o, f"se_{a}"] for o, a in best.items()], t.index)
    return pd.DataFrame(
        {
            "best": best,
            "diff": t[f"gap_{ours}"] - bgap,
            "se": np.hypot(t[f"se_{ours}"], bse),
        }
    )


def _ours_label() -> str:
    from legs_jax.core import methods  # jax: kept out of the figures' start-up

    return methods.get(decl.OURS).card.label


def _short(arm: str) -> str:
    """A method's short label from its card; a grid point or variant as named."""
    from legs_jax.core import methods  # jax: kept out of the figures' start-up

    return methods.get(arm).card.short_label if arm in methods.names() else arm


def ours_figure(s: Mapping[str, Any], path) -> Any:
    """Our method against the lowest other arm: the map's cells (left) and every
    problem with ± Z standard errors (right)."""
    plt = pyplot()
    t = s["table"]
    vb = versus_best(t)
    shapes, aucs, xs, ys = _levels(t)
    fig, (ax, bx) = plt.subplots(
        1, 2, figsize=(12.5, 6.2), gridspec_kw=dict(width_ratios=[1, 1.25])
    )
    grid = np.full((len(aucs), len(shapes)), np.nan)
    text = np.full(grid.shape, "", dtype=object)
    for name, r in t[t["on_map"]].iterrows():
        hit = [i for i, a in enumerate(aucs) if np.isclose(a, r["auc_level"])]
        if r["shape"] in shapes and hit:
            i, j = hit[0], shapes.index(r["shape"])
            d, se = float(vb.loc[name, "diff"]), float(vb.loc[name, "se"])
            grid[i, j] = d
            star = "*" if d > Z * se else ""
            text[i, j] = f"{d:+.3f}{star}\n{_short(vb.loc[name, 'best'])}"
    lim = max(float(np.nanmax(np.abs(vb["diff"]))), 0.005)
    cmap = plt.get_cmap("RdBu_r")
    im = ax.imshow(grid, origin="lower", cmap=cmap, vmin=-lim, vmax=lim, aspect="auto")
    for i in range(len(aucs)):
        for j in range(len(shapes)):
            if text[i, j]:
                ax.text(j, i, text[i, j], ha="center", va="center", fontsize=6.5)
    _map_axes(ax, shapes, xs, ys)
    ax.set_title("ours − the lowest other arm (named in the cell)", fontsize=10)
    fig.colorbar(im, ax=ax, shrink=0.8, label="final gap difference")
    order = vb.sort_values("diff")
    y = np.arange(len(order))
    worse = order["diff"] > Z * order["se"]
    bx.errorbar(
        order["diff"],
        y,
        xerr=Z * order["se"],
        fmt="none",
        ecolor="0.4",
        elinewidth=1,
        capsize=2,
    )
    bx.scatter(
        order["diff"], y, c=np.where(worse, "#d62728", "#1f77b4"), s=18, zorder=3
    )
    bx.axvline(0.0, color="black", lw=0.8)
    bx.set_yticks(y)
    bx.set_yticklabels(
        [f"{n} ({_short(b)})" for n, b in zip(order.index, order["best"], strict=True)],
        fontsize=6.5,
    )
    bx.set_xlabel(f"ours − the lowest other arm (± {Z:g} SE; red: above by more)")
    bx.set_title("every generated problem", fontsize=10)
    fig.suptitle(_ours_label() + " against the lowest other arm", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _ours_lines(t: pd.DataFrame) -> list[str]:
    """Our method on every problem against the lowest other arm (the oracle
    excluded) and, where it ran, against the method it builds on, Bayes-UCB
    (K=2000)."""
    base = "bayes_ucb_2000"
    vb = versus_best(t)
    if vb is None:
        return []
    worse = t.index[vb["diff"] > Z * vb["se"]]
    why = sorted({_short(b) for b in vb["best"][worse]})
    line = (
        f"- {_ours_label()}: above the lowest other arm by more "
        f"than {Z:g} SE on {len(worse)} of {len(t)} problems ({_names(list(worse))}"
        f"; the lowest there: {', '.join(why) or 'none'})"
    )
    if f"gap_{base}" in t:
        gap, se = t[f"gap_{decl.OURS}"], t[f"se_{decl.OURS}"]
        dbase = gap - t[f"gap_{base}"]
        dse = np.hypot(se, t[f"se_{base}"])
        lower, higher = t.index[dbase < -Z * dse], t.index[dbase > Z * dse]
        line += (
            f"; against Bayes-UCB (K=2000), which it builds on, "
            f"{fmt(float(dbase.mean()))} on average, lower by more than {Z:g} SE "
            f"on {len(lower)} ({_names(list(lower))}) and higher on {len(higher)} "
            f"({_names(list(higher))})"
        )
    return [
        line + ".",
        "",
        f"![{_ours_label()} against the lowest other arm on every generated "
        "problem](figures/regimes_ours.png)",
        "",
    ]


def _axis_lines(t: pd.DataFrame) -> list[str]:
    """How LEGS − BORGES (K=100) moves along each axis of the map."""
    if "diff_borges_100" not in t:
        return []
    col = "diff_borges_100"
    main = t[t["on_map"]]
    out = []
    if len(main):
        by_shape = main.groupby("shape")[col].mean().reindex(decl.SHAPES).dropna()
        by_auc = main.groupby("auc_level")[col].mean()
        out.append(
            "- Along the map's axes, LEGS − BORGES (K=100) averaged over the other "
            "axis: by shape "
            + ", ".join(f"{k} {fmt(v)}" for k, v in by_shape.items())
            + "; by prior C-index "
            + ", ".join(f"{k:.2f} {fmt(v)}" for k, v in by_auc.items())
            + "."
        )
    side = t.drop(index=main.index, errors="ignore")
    if len(side):
        out.append(
            "- Off the map (calibration, share of excellent grasps, λ's "
            "concentration): "
            + "; ".join(
                f"`{n}` {fmt(r[col])} ± {fmt(r['dse_borges_100'])}"
                for n, r in side.iterrows()
            )
            + "."
        )
    return out


SECTIONS = ((45, _section),)
