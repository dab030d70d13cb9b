"""What the ``prior_synthetic`` experiment makes: the learned prior's quality, and
Table I's Dex-Net rows with each prior beside the paper's.

``main`` runs every object with the prior its problem files carry by default (the
learned network of :mod:`precompute.learned`); this experiment runs the 13 Dex-Net
objects with the synthetic stand-in (q from p plus noise, :mod:`precompute.prior`).
The report sets the two side by side: Table I's rows, the win counts and the
stopping bound, each with the paper's, and the learned prior's held-out figures on
generated objects (its model card's ``metrics.json``) and on each evaluation set
(``results/precompute``) beside GQ-CNN's published accuracy.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from experiments.main.tables import ARMS, PAPER_TABLE1, PAPER_WINS
from legs_jax.report import analysis as an
from legs_jax.report.document import Num, Table, fmt, pct, to_markdown, write_pair
from legs_jax.report.figures import Results, Run, write_csv

NAME = "prior_synthetic"
SET = "dexnet_adv"  # the set this experiment runs
# Dex-Net 2.0 (Mahler et al., RSS 2017): GQ-CNN's accuracy on held-out synthetic
# data (its only published figure of this kind).
GQCNN_ACCURACY = 0.857
# The folder of the learned prior's weights, model card and metrics.
WEIGHTS = Path(__file__).resolve().parents[2] / "precompute" / "prior_weights"


def _rows(t1: pd.DataFrame) -> dict[str, tuple[float, float, int]]:
    """method -> (mean, se, objects) of the default arms of SET in a Table I."""
    d = t1[(t1["set"] == SET) & (t1["variant"] == "")]
    return {
        r.method: (float(r.mean), float(r.se), int(r.n_objects)) for r in d.itertuples()
    }


def _bound(checks: pd.DataFrame | None, objects) -> dict[str, float] | None:
    """Accuracy and tightness of the paper's stopping bound over the checks of
    ``objects`` (None without checks)."""
    if checks is None:
        return None
    c = checks[checks["object"].isin(objects) & (checks["method"] == ARMS.proposed)]
    if c.empty:
        return None
    s = an.bound_summary(c).set_index("bound")
    if "all" not in s.index:
        return None
    return {k: float(s.loc["all", k]) for k in ("accuracy", "tightness", "n_checks")}


def comparison(res: Results, main: Mapping | None) -> dict[str, Any]:
    """Both priors' Dex-Net rows, win counts and stopping bounds (the learned
    prior's from ``main``, restricted to the objects this experiment ran)."""
    runs = res.table(NAME, "runs")
    gaps = an.object_gaps(runs, ARMS)
    objects = sorted(set(gaps.loc[gaps["set"] == SET, "object"]))
    methods = sorted(set(gaps["method"]))
    competitors = [m for m in ARMS.competitors if m in methods]
    out: dict[str, Any] = {"objects": objects, "competitors": competitors}
    out["synthetic"] = dict(
        table1=an.table_one(gaps, ARMS),
        wins=an.win_counts(gaps, competitors),
        bound=_bound(
            res.table(NAME, "checks") if res.has(NAME, "checks") else None, objects
        ),
    )
    if main is not None:
        g = main["gaps"]
        g = g[
            (g["set"] == SET)
            & g["object"].isin(objects)
            & g["method"].isin(methods)
            & (g["variant"] == "")
        ]
        out["learned"] = dict(
            table1=an.table_one(g, ARMS),
            wins=an.win_counts(g, competitors),
            bound=_bound(
                res.table("main", "checks") if res.has("main", "checks") else None,
                objects,
            ),
        )
    return out


def comparison_table(cmp: Mapping) -> Table:
    """Dex-Net rows: learned prior, synthetic prior, paper."""
    syn = _rows(cmp["synthetic"]["table1"])
    lrn = _rows(cmp["learned"]["table1"]) if "learned" in cmp else {}
    paper = PAPER_TABLE1.get(SET, {})
    rows = []
    for m in ARMS.methods:
        if m not in syn:
            continue
        cells = [ARMS.label(m)]
        for src in (lrn, syn):
            v = src.get(m)
            cells.append(Num(v[0], v[1]) if v else "n/a")
        p = paper.get(m)
        cells.append(Num(p[0], p[1], digits=2) if p else "–")
        rows.append(cells)
    n = len(cmp["objects"])
    return Table(
        header=[
            "method",
            f"learned prior ({n} objects)",
            f"synthetic prior ({n} objects)",
            "paper (GQ-CNN, 14 objects)",
        ],
        rows=rows,
        align="lccc",
        caption="Optimality gap at H = 3000 on the Dex-Net objects with each prior "
        "(mean ± standard error across objects)",
        label="tab:priors",
    )


def _win_line(cmp: Mapping) -> str:
    parts = []
    for kind in ("learned", "synthetic"):
        if kind not in cmp:
            continue
        w = cmp[kind]["wins"].set_index("method")
        if ARMS.proposed not in w.index:
            continue
        r = w.loc[ARMS.proposed]
        parts.append(f"{int(r.wins)} of {int(r.n_objects)} with the {kind} prior")
    paper = PAPER_WINS.get(SET, {}).get(ARMS.proposed)
    line = f"- {ARMS.label(ARMS.proposed)} wins " + " and ".join(parts)
    if paper:
        line += f" (paper: {paper[0]} of {paper[1]})"
    return line + "."


def _gap_line(cmp: Mapping) -> str | None:
    """Which prior gives the proposed method the lower gap, and whether the
    difference is within the standard errors."""
    if "learned" not in cmp:
        return None
    lrn = _rows(cmp["learned"]["table1"]).get(ARMS.proposed)
    syn = _rows(cmp["synthetic"]["table1"]).get(ARMS.proposed)
    if not lrn or not syn:
        return None
    diff = lrn[0] - syn[0]
    se = math.hypot(lrn[1], syn[1])
    which = "learned" if diff < 0 else "synthetic"
    verdict = (
        "within the combined standard error"
        if abs(diff) <= se
        else f"{abs(diff) / se:.1f} combined standard errors apart"
    )
    return (
        f"- {ARMS.label(ARMS.proposed)}'s gap is {fmt(lrn[0])} with the learned prior "
        f"and {fmt(syn[0])} with the synthetic one: lower with the {which} prior, "
        f"{verdict} ({fmt(se)})."
    )


def _ranking_line(cmp: Mapping) -> list[str]:
    out = []
    for kind in ("learned", "synthetic"):
        if kind not in cmp:
            continue
        rows = {
            m: v
            for m, v in _rows(cmp[kind]["table1"]).items()
            if m in cmp["competitors"]
        }
        if not rows:
            continue
        best = min(rows, key=lambda m: rows[m][0])
        out.append(
            f"- Lowest competitor row with the {kind} prior: {ARMS.label(best)} "
            f"({fmt(rows[best][0])})."
        )
    return out


def _bound_line(cmp: Mapping) -> str | None:
    parts = []
    for kind in ("learned", "synthetic"):
        b = cmp.get(kind, {}).get("bound")
        if b:
            parts.append(
                f"{pct(b['accuracy'])} of {int(b['n_checks'])} checks with the "
                f"{kind} prior"
            )
    if not parts:
        return None
    return (
        f"- The stopping bound of {ARMS.label(ARMS.proposed)} is valid at "
        + " and at ".join(parts)
        + " on these objects (paper: 95.8 % over both sets)."
    )


def prior_quality(results: Path) -> dict[str, Any]:
    """The learned prior's figures: held-out generated objects (metrics.json) and
    the evaluation sets' objects (results/precompute, both priors where present)."""
    out: dict[str, Any] = {}
    mf = WEIGHTS / "metrics.json"
    if mf.is_file():
        with open(mf) as fh:
            m = json.load(fh)
        out["generated"] = m.get("metrics", {}).get("test")
        out["weights_sha256"] = m.get("weights_sha256")
    sets = []
    for kind, path in (
        ("learned", results / "precompute" / "summary.csv"),
        ("synthetic", results / "precompute" / "prior-synthetic" / "summary.csv"),
    ):
        if not path.is_file():
            continue
        d = pd.read_csv(path)
        d = d[d["prior"] == kind]
        for set_, g in d.groupby("set", sort=False):
            sets.append(
                dict(
                    set=set_,
                    prior=kind,
                    objects=len(g),
                    roc_auc=float(g["prior_auc"].mean()),
                    corr=float(g["prior_truth_corr"].mean()),
                )
            )
    out["sets"] = pd.DataFrame(sets)
    return out


def quality_table(q: Mapping) -> Table:
    rows = []
    gen = q.get("generated")
    if gen:
        rows.append(
            [
                "generated test objects (never trained on)",
                "learned",
                Num(gen["roc_auc"]),
                Num(gen["corr_q_p"], digits=2),
                Num(gen["accuracy"], percent=True, digits=1),
            ]
        )
    for r in q["sets"].itertuples() if len(q.get("sets", [])) else ():
        rows.append(
            [
                f"{an.SET_LABELS.get(r.set, r.set)} ({r.objects} objects, mean)",
                r.prior,
                Num(r.roc_auc),
                Num(r.corr, digits=2),
                "–",
            ]
        )
    rows.append(
        [
            "Dex-Net 2.0's GQ-CNN, held-out synthetic data (published)",
            "–",
            "–",
            "–",
            Num(GQCNN_ACCURACY, percent=True, digits=1),
        ]
    )
    return Table(
        header=["grasps of", "prior", "ROC AUC (p ≥ 0.5)", "corr(q, p)", "accuracy"],
        rows=rows,
        align="lcccc",
        caption="How well each prior ranks grasps",
        label="tab:prior-quality",
    )


# ====================================================================== steps
def _step(run: Run) -> None:
    cmp = comparison(run.res, run.ctx.get("main"))
    cmp["quality"] = prior_quality(run.res.root)
    run.ctx[NAME] = cmp
    if "learned" in cmp:
        run.written += write_pair("priors", comparison_table(cmp), run.tables)
    run.written += write_pair(
        "prior_quality", quality_table(cmp["quality"]), run.tables
    )
    both = pd.concat(
        [cmp[k]["table1"].assign(prior=k) for k in ("learned", "synthetic") if k in cmp]
    )
    run.written.append(write_csv(both, run.tables / "priors.csv"))


STEPS = (("Table I with each prior", _step),)


def _quality_lines(q: Mapping) -> list[str]:
    """How the network does on generated objects against the evaluation sets."""
    gen, sets = q.get("generated"), q.get("sets")
    if gen is None or sets is None or not len(sets):
        return []
    lrn = sets[sets["prior"] == "learned"]
    if not len(lrn):
        return []
    low = lrn.loc[lrn["roc_auc"].idxmin()]
    auc, name = float(low.roc_auc), an.SET_LABELS.get(low.set, low.set)
    harder = auc < gen["roc_auc"]
    verdict = (
        "the evaluation objects are harder for it than the generated ones, the "
        "regime LEGS is built for."
        if harder
        else "no lower than on generated objects."
    )
    text = (
        f"- On held-out generated objects the network's ROC AUC is "
        f"{fmt(gen['roc_auc'])} (accuracy {pct(gen['accuracy'])}, GQ-CNN's "
        f"published {pct(GQCNN_ACCURACY)}); on the {name} objects it "
        f"{'falls to' if harder else 'is'} {fmt(auc)}: {verdict}"
    )
    return [text]


# ==================================================================== report
def _section(ctx: Mapping) -> list[str]:
    L = ["## The prior: learned network and synthetic stand-in", ""]
    cmp = ctx.get(NAME)
    if not cmp:
        return L + ["_Not available: the `prior_synthetic` results are missing._", ""]
    q = cmp["quality"]
    L += [
        "The problem files carry the learned prior by default: a small GQ-CNN-style "
        "network that sees an overhead depth image and the grasp, trained on "
        "generated objects only ([model card](../precompute/prior_weights/"
        "MODEL_CARD.md)); it never reads p. The synthetic stand-in (q from p plus "
        "noise) is kept for comparison on the Dex-Net objects.",
        "",
        to_markdown(quality_table(q)),
        "![Reliability of the learned prior on the evaluation sets]"
        "(precompute/figures/prior_reliability.png)",
        "",
    ]
    L += _quality_lines(q)
    if "learned" in cmp:
        L += ["", to_markdown(comparison_table(cmp))]
    lines = [_gap_line(cmp), *_ranking_line(cmp), _win_line(cmp), _bound_line(cmp)]
    L += [x for x in lines if x]
    L += [
        "",
        "Both columns are this repository's runs on the same objects, trials and "
        "seeds; only q differs. Nothing was tuned to the paper's numbers.",
        "",
    ]
    return L


SECTIONS = ((15, _section),)
