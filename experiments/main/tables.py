"""Table I of the ``main`` experiment, its win counts and per-object gaps, and the
problem model before and after (read from ``results/previous``).

The paper's own numbers (``PAPER_*``) are kept here so that tables and the report
can show both.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from experiments.main import sweep
from legs_jax.report import analysis as an
from legs_jax.report.document import Cell, Num, Table, horizon_text, write_pair
from legs_jax.report.figures import Results, write_csv

# How Table I orders, labels and compares the arms (the main experiment's
# declarations; the case study and the prior comparison show the same arms).
ARMS = an.Arms(
    order=tuple(sweep.TABLE_ORDER),
    declared=tuple(dict.fromkeys(m for m, _, _ in sweep.ARMS)),
    variants=dict(sweep.VARIANTS),
    proposed=sweep.PROPOSED,
)

# Object counts of the paper's data sets.
PAPER_OBJECTS = {"dexnet_adv": 14, "egad_eval": 39}


# Table I of the paper: optimality gap at H = 3000, (mean, SE) across objects, per
# set; a row per method as in the paper, the sets in the order of PAPER_SETS.
PAPER_SETS = ("dexnet_adv", "egad_eval")
_PAPER_ROWS = {
    "dexnet": ((0.56, 0.07), (0.59, 0.03)),
    "tql": ((0.23, 0.08), (0.32, 0.04)),
    "borges_100": ((0.13, 0.07), (0.25, 0.04)),
    "k100_ub": ((0.08, 0.04), (0.13, 0.03)),
    "borges_2000": ((0.04, 0.03), (0.17, 0.03)),
    "legs_no_as": ((0.22, 0.06), (0.28, 0.04)),
    "legs": ((0.04, 0.03), (0.14, 0.03)),
}
PAPER_TABLE1 = {
    s: {m: row[i] for m, row in _PAPER_ROWS.items()} for i, s in enumerate(PAPER_SETS)
}


# Win counts stated in the paper (Section 5.3): (wins, objects).
PAPER_WINS = {
    "dexnet_adv": {"legs": (10, 14), "borges_2000": (5, 14)},
    "egad_eval": {"legs": (25, 39), "borges_2000": (14, 39)},
}


def _set_header(set_: str, n: int) -> str:
    return f"{an.SET_LABELS.get(set_, set_)}, ours ({n} objects)"


def _paper_header(set_: str) -> str:
    return f"paper ({PAPER_OBJECTS[set_]} objects)"


def table_one_table(
    t1: pd.DataFrame, horizon: int | None = None, prior: str = "unknown"
) -> Table:
    """Table I: one row per arm, per set our mean ± SE beside the paper's."""
    sets = an.order_sets(t1["set"])
    arms = ARMS.of_table(t1)
    for s in sets:
        for m in PAPER_TABLE1.get(s, {}):
            if (m, "") not in arms:
                arms = ARMS.sort([*arms, (m, "")])
    header = ["Method"]
    align = "l"
    for s in sets:
        n = int(t1.loc[t1["set"] == s, "n_objects"].max())
        header.append(_set_header(s, n))
        align += "c"
        if s in PAPER_TABLE1:
            header.append(_paper_header(s))
            align += "c"
    # Bold the lowest mean of the compared methods (the paper's columns, not the
    # oracle row, not a variant or an extra row), as the paper does; ties within
    # 0.005 are all bold.
    best = {}
    oracle = an.oracle_methods()
    compared = t1["method"].isin(ARMS.competitors) & (t1["variant"] == "")
    for s in sets:
        d = t1[(t1["set"] == s) & compared]
        best[s] = float(d["mean"].min()) if len(d) else math.nan
    rows = []
    for m, v in arms:
        row: list[Cell] = [ARMS.label(m, v)]
        for s in sets:
            d = t1[(t1["set"] == s) & (t1["method"] == m) & (t1["variant"] == v)]
            if len(d):
                mean, se = float(d["mean"].iloc[0]), float(d["se"].iloc[0])
                bold = m in ARMS.competitors and not v and mean <= best[s] + 0.005
                row.append(Num(mean, se, 3, bold))
            else:
                row.append("—")
            if s in PAPER_TABLE1:
                paper = PAPER_TABLE1[s]
                if v == "" and m in paper:
                    pm, pse = paper[m]
                    low = min(x[0] for k, x in paper.items() if k not in oracle)
                    row.append(Num(pm, pse, 2, m not in oracle and pm <= low))
                else:
                    row.append("—")
        rows.append(row)
    notes = [
        f"Optimality gap at {horizon_text(horizon)} (lower is better): per object "
        "the mean over its "
        "T × R runs, then mean ± standard error across the objects of the set.",
        f"The prior of every method is {an.prior_words(prior)}, not GQ-CNN "
        "(Dex-Net 4.0); the Dex-Net row is greedy on it and the K_s=100 upper "
        "bound takes the best grasp among its top 100.",
        "Bold: lowest gap of the compared methods, the paper's (the upper bound "
        "is an oracle row; variants and extra rows are shown, not compared), ties "
        "within 0.005 included.",
    ]
    return Table(
        header,
        rows,
        align,
        caption=f"Table I: optimality gap at {horizon_text(horizon)}, ours beside "
        "the paper's",
        label="tab:table1",
        notes=notes,
    )


def wins_table(wins: pd.DataFrame, wins_all: pd.DataFrame | None = None) -> Table:
    """Win counts per method and set, beside the paper's counts; with
    ``wins_all`` (counts among every row, the extra rows included) a column of
    those per set and a row per extra method."""
    sets = an.order_sets(wins["set"])
    header = ["Method"]
    align = "l"
    for s in sets:
        header.append(f"{an.SET_LABELS.get(s, s)}, ours")
        align += "c"
        if s in PAPER_WINS:
            header.append("paper")
            align += "c"
        if wins_all is not None:
            header.append("among all rows")
            align += "c"

    def count(w: pd.DataFrame, s: str, m: str) -> str:
        d = w[(w["set"] == s) & (w["method"] == m)]
        if not len(d):
            return "—"
        return f"{int(d['wins'].iloc[0])}/{int(d['n_objects'].iloc[0])}"

    methods = ARMS.competitors
    if wins_all is not None:
        methods = tuple(m for m in ARMS.rivals if m in set(wins_all["method"]))
    rows = []
    for m in methods:
        row: list[Cell] = [ARMS.label(m)]
        for s in sets:
            row.append(count(wins, s, m))
            if s in PAPER_WINS:
                p = PAPER_WINS[s].get(m)
                row.append(f"{p[0]}/{p[1]}" if p else "—")
            if wins_all is not None:
                row.append(count(wins_all, s, m))
        rows.append(row)
    notes = [
        f"A method wins an object when its mean final gap is at most every other "
        f"compared method's + {an.WIN_TOLERANCE} (Dex-Net, TQL, both BORGES, "
        "LEGS(-AS), LEGS; the upper bound is not compared). Several methods can "
        "win the same object.",
        "The paper states counts for LEGS and BORGES (K_s=2000) only.",
    ]
    if wins_all is not None:
        notes.append(
            "Among all rows: the same rule with the extra rows (Bayes-UCB, ours) "
            "compared too; an object on which every row is within two combined "
            "standard errors of the best has no winner."
        )
    return Table(
        header,
        rows,
        align,
        caption="Objects won per method (ours beside the paper's)",
        label="tab:wins",
        notes=notes,
    )


def per_object_table(
    gaps: pd.DataFrame, win: pd.DataFrame, prior: str = "unknown"
) -> Table:
    """Final gap of every arm on every object (mean ± SE over its runs)."""
    arms = ARMS.of_table(gaps)
    short = {
        a: ARMS.declaration(*a).get("short_label") or ARMS.label(*a)
        for a in {*arms, *((m, "") for m in ARMS.competitors)}
    }
    header = ["Set", "Object", *[short[a] for a in arms]]
    header.append("Winners")
    rows = []
    keyed = gaps.set_index(["object", "method", "variant"])
    win_by_obj = win.set_index("object") if len(win) else None
    objects = gaps[["set", "object"]].drop_duplicates()
    any_noise = False
    for s, o in zip(objects["set"], objects["object"], strict=True):
        row: list[Cell] = [an.SET_LABELS.get(s, s), o]
        winners = []
        if win_by_obj is not None and o in win_by_obj.index:
            winners = [m for m in ARMS.competitors if bool(win_by_obj.loc[o, m])]
        for m, v in arms:
            if (o, m, v) in keyed.index:
                r = keyed.loc[(o, m, v)]
                bold = v == "" and m in winners
                row.append(Num(float(r["gap_mean"]), float(r["gap_se"]), 3, bold))
            else:
                row.append("—")
        noise = (
            win_by_obj is not None
            and o in win_by_obj.index
            and bool(win_by_obj.loc[o, "within_noise"])
        )
        any_noise = any_noise or noise
        row.append(
            "none (all within noise)"
            if noise
            else ", ".join(short.get((m, ""), m) for m in winners) or "—"
        )
        rows.append(row)
    notes = [
        "Mean ± standard error of the final gap over each object's T × R runs. "
        "Bold: the object's winners (mean final gap at most every other compared "
        f"method's + {an.WIN_TOLERANCE}).",
        f"*Dex-Net: greedy on the {prior} prior (no online learning).",
    ]
    if any_noise:
        notes.append(
            "No winner is named for an object on which every compared method's "
            "mean is within two combined standard errors of the best one's: the "
            "runs do not tell the methods apart there."
        )
    return Table(
        header,
        rows,
        "ll" + "c" * len(arms) + "l",
        caption="Final optimality gap per object",
        label="tab:per-object",
        notes=notes,
    )


def main_tables(res: Results, out: Path) -> tuple[list[Path], dict[str, Any]]:
    runs = res.table("main", "runs")
    gaps = an.object_gaps(runs, ARMS)
    t1 = an.table_one(gaps, ARMS)
    wins = an.win_counts(gaps, ARMS.competitors)
    win = an.winners(gaps, ARMS.competitors)
    rivals = [m for m in ARMS.rivals if m in set(gaps["method"])]
    extra = set(rivals) - set(ARMS.competitors)
    wins_all = an.win_counts(gaps, rivals) if extra else None
    files = []
    horizon = int(runs["horizon"].max()) if "horizon" in runs.columns else None
    prior = an.prior_kind(res)
    files += write_pair("table1", table_one_table(t1, horizon, prior), out)
    files += write_pair("wins", wins_table(wins, wins_all), out)
    files += write_pair("per_object", per_object_table(gaps, win, prior), out)
    files.append(write_csv(t1, out / "table1.csv"))
    files.append(write_csv(gaps, out / "per_object.csv"))
    files.append(write_csv(wins, out / "wins.csv"))
    if wins_all is not None:
        files.append(write_csv(wins_all, out / "wins_all_rows.csv"))
    curves = res.table("main", "curves") if res.has("main", "curves") else None
    return files, dict(
        curves=curves,
        gaps=gaps,
        table1=t1,
        wins=wins,
        wins_all=wins_all,
        winners=win,
        runs=runs,
        horizon=horizon,
        prior=prior,
    )


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
