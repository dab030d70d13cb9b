"""Tables (Markdown, LaTeX, CSV) and the reproduction report, as text.

Pure functions from the DataFrames of ``legs_jax.report.analysis`` to strings: the same
inputs always give byte-identical text (no dates, no machine names), so tables
regenerated from committed results match the committed tables exactly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from legs_jax._files import atomic_write
from legs_jax.report import analysis as an

__all__ = [
    "Appendix",
    "Cell",
    "Num",
    "Table",
    "appendix_section",
    "appendix_table",
    "build_report",
    "fmt",
    "horizon_text",
    "pct",
    "tex_escape",
    "to_csv",
    "to_latex",
    "to_markdown",
    "write_pair",
    "write_text",
]


# --------------------------------------------------------------------- cells
@dataclasses.dataclass(frozen=True)
class Num:
    """A number, optionally with a standard error, a unit and bold face."""

    value: float
    se: float = float("nan")
    digits: int = 3
    bold: bool = False
    percent: bool = False

    def text(self, latex: bool = False) -> str:
        if self.value is None or not math.isfinite(self.value):
            return "n/a"
        scale = 100.0 if self.percent else 1.0
        v = f"{self.value * scale:.{self.digits}f}"
        if self.se is not None and math.isfinite(self.se):
            pm = r" \pm " if latex else " ± "
            v += f"{pm}{self.se * scale:.{self.digits}f}"
        if self.percent:
            v += r"\,\%" if latex else " %"
        if latex:
            v = f"$\\mathbf{{{v}}}$" if self.bold else f"${v}$"
        elif self.bold:
            v = f"**{v}**"
        return v


Cell = str | Num


@dataclasses.dataclass(frozen=True)
class Table:
    """A table ready to print: header, rows of cells, column alignment, notes."""

    header: Sequence[str]
    rows: Sequence[Sequence[Cell]]
    align: str  # one of "l", "c", "r" per column
    caption: str = ""
    label: str = ""
    notes: Sequence[str] = ()


_TEX_ESCAPES = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}
_TEX_SYMBOLS = {
    "Σ_s λ_s p[s, π_t(s)]": r"$\sum_s \lambda_s p[s, \pi_t(s)]$",
    "p̂_ℓ": r"$\hat{p}_\ell$",
    "p̂*": r"$\hat{p}^*$",
    "ρ_min": r"$\rho_{\min}$",
    "K_s": r"$K_s$",
    "ℓ": r"$\ell$",
    "Σ": r"$\Sigma$",
    "π": r"$\pi$",
    "−": r"$-$",
    "≈": r"$\approx$",
    "±": r"$\pm$",
    "≤": r"$\le$",
    "≥": r"$\ge$",
    "δ": r"$\delta$",
    "ρ": r"$\rho$",
    "Δ": r"$\Delta$",
    "×": r"$\times$",
    "—": "---",
    "–": "--",
    "p̂": r"$\hat{p}$",
    "λ": r"$\lambda$",
}


_TEX_TOKENS = sorted(_TEX_SYMBOLS, key=len, reverse=True)


def tex_escape(text: str) -> str:
    """Plain text as LaTeX (special characters escaped, symbols as math)."""
    out = []
    i = 0
    while i < len(text):
        for tok in _TEX_TOKENS:
            if text.startswith(tok, i):
                out.append(_TEX_SYMBOLS[tok])
                i += len(tok)
                break
        else:
            ch = text[i]
            out.append(_TEX_ESCAPES.get(ch, ch))
            i += 1
    return "".join(out)


def _md_cell(c: Cell) -> str:
    return c.text(False) if isinstance(c, Num) else str(c).replace("|", "\\|")


def to_markdown(t: Table) -> str:
    """GitHub Markdown: caption as a bold line, the table, notes as a list."""
    cols = len(t.header)
    sep = {"l": ":---", "c": ":---:", "r": "---:"}
    lines = []
    if t.caption:
        lines += [f"**{t.caption}**", ""]
    lines.append("| " + " | ".join(t.header) + " |")
    lines.append("|" + "|".join(sep[a] for a in t.align[:cols]) + "|")
    for row in t.rows:
        lines.append("| " + " | ".join(_md_cell(c) for c in row) + " |")
    if t.notes:
        lines.append("")
        lines += [f"- {n}" for n in t.notes]
    return "\n".join(lines) + "\n"


def to_latex(t: Table) -> str:
    """A booktabs ``table`` environment (needs ``booktabs``); tables of more than
    six columns span both columns (``table*``) and are scaled to the text width
    (needs ``graphicx``)."""
    wide = len(t.header) > 6
    env = "table*" if wide else "table"
    lines = [
        r"\begin{" + env + "}[t]",
        r"\centering",
        r"\small",
    ]
    if wide:
        lines.append(r"\resizebox{\textwidth}{!}{%")
    lines += [
        r"\begin{tabular}{" + t.align + "}",
        r"\toprule",
        " & ".join(tex_escape(h) for h in t.header) + r" \\",
        r"\midrule",
    ]
    for row in t.rows:
        cells = [c.text(True) if isinstance(c, Num) else tex_escape(c) for c in row]
        lines.append(" & ".join(cells) + r" \\")
    lines.append(r"\bottomrule")
    lines.append(r"\end{tabular}" + ("}" if wide else ""))
    caption = t.caption
    if t.notes:
        caption = (caption + ". " if caption else "") + " ".join(t.notes)
    if caption:
        lines.append(r"\caption{" + tex_escape(caption) + "}")
    if t.label:
        lines.append(r"\label{" + t.label + "}")
    lines.append(r"\end{" + env + "}")
    return "\n".join(lines) + "\n"


def to_csv(df: pd.DataFrame) -> str:
    """CSV with 6 significant digits, so that files are stable across runs."""
    return df.to_csv(index=False, float_format="%.6g", lineterminator="\n")


# ------------------------------------------------------------------ Table I


def horizon_text(horizon: int | None) -> str:
    if horizon is None or horizon == 3000:
        return "H = 3000"
    return f"H = {horizon} (paper: H = 3000)"


# ------------------------------------------------------------------ appendix
_SYMBOL = {"s": "s", "delta": "δ"}


def _param_text(param: str, value: float) -> str:
    return f"{value:.2f}" if param == "delta" else f"{value:g}"


@dataclasses.dataclass(frozen=True)
class Appendix:
    """An appendix experiment: one method's final gap over a grid of one
    hyperparameter ``param`` (the other, ``other``, held fixed), beside the paper's
    numbers ``paper`` (value -> (mean, SE), on the bar clamp)."""

    experiment: str
    param: str
    name: str  # header of the parameter's column
    caption: str
    other: str
    paper_fixed: float  # the paper's value of ``other``
    paper: Mapping[float, tuple[float, float]]
    method: str  # the one method of the experiment's sweep

    @property
    def paper_best(self) -> float:
        """The paper's best value of ``param`` (lowest mean gap)."""
        return min(self.paper, key=lambda v: self.paper[v][0])


def appendix_table(
    sweep: pd.DataFrame,
    spec: Appendix,
    fixed: float | None = None,
    horizon: int | None = None,
) -> Table:
    """An appendix table: final gap against ``spec.param`` beside the paper's.

    ``fixed`` is the value of the other hyperparameter (δ for the s table, s for
    the δ table) in our runs; ``horizon`` our H.
    """
    param, name, caption = spec.param, spec.name, spec.caption
    other, paper_fixed = spec.other, spec.paper_fixed
    setting = f"{_SYMBOL[other]} = {_param_text(other, paper_fixed)}"
    if fixed is not None and not math.isclose(fixed, paper_fixed):
        setting = (
            f"{_SYMBOL[other]} = {_param_text(other, fixed)}; paper: "
            f"{_SYMBOL[other]} = {_param_text(other, paper_fixed)}"
        )
    caption = f"{caption} (LEGS, {setting})"
    paper = spec.paper
    objects = list(dict.fromkeys(sweep["object"]))
    values = sorted(set(sweep[param].round(6)) | set(paper))
    header = [name]
    for o in objects:
        header += [f"{o}, ours", "paper" if o == "bar_clamp" else "—"]
    rows = []
    n_runs = sorted(set(int(n) for n in sweep["n_runs"]))
    runs_text = "/".join(str(n) for n in n_runs)
    p_best = min(v[0] for v in paper.values())
    for val in values:
        row: list[Cell] = [_param_text(param, val)]
        for o in objects:
            d = sweep[(sweep["object"] == o)]
            best = float(d["mean"].min())
            hit = d[np.isclose(d[param], val)]
            if len(hit):
                mean, se = float(hit["mean"].iloc[0]), float(hit["se"].iloc[0])
                row.append(Num(mean, se, 3, mean <= best))
            else:
                row.append("—")
            pv = paper.get(round(val, 6)) if o == "bar_clamp" else None
            row.append(Num(pv[0], pv[1], 3, pv[0] <= p_best) if pv else "—")
        rows.append(row)
    return Table(
        header,
        rows,
        "c" * len(header),
        caption=caption + f", final optimality gap at {horizon_text(horizon)}",
        label=f"tab:appendix-{param}",
        notes=[
            f"Ours: mean ± standard error over the {runs_text} runs (T × R) of "
            "the object; the paper does not say over what its standard error is "
            "taken (it ran 10 trials × 10 rollouts). Bold: lowest gap of the column."
        ],
    )


def write_pair(stem, table: Table, folder) -> list:
    """Write ``<stem>.md`` and ``<stem>.tex`` into ``folder``; returns the paths."""
    from pathlib import Path

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for ext, text in (("md", to_markdown(table)), ("tex", to_latex(table))):
        p = folder / f"{stem}.{ext}"
        _write_text(p, text)
        out.append(p)
    return out


def _write_text(path, text: str) -> None:
    atomic_write(path, lambda fh: fh.write(text), text=True)


def write_text(path, text: str) -> None:
    """Write ``text`` atomically (UTF-8, LF line ends)."""
    _write_text(path, text)


# ==================================================================== report


def fmt(x: float | None, d: int = 3) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x:.{d}f}"


def pct(x: float | None, d: int = 1) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{100 * x:.{d}f} %"


def _results_section(ctx: Mapping) -> list[str]:
    res = ctx["results"]
    lines = [
        "## Results used",
        "",
        "| experiment | status | objects | trials × rollouts | horizon | computed at |",
        "|:---|:---|---:|:---:|---:|:---|",
    ]
    smoke, unshipped = [], []
    for exp in ctx["experiments"]:
        if not res.has(exp, "runs"):
            lines.append(f"| {exp} | not run | — | — | — | — |")
            continue
        try:
            runs = res.table(exp, "runs")
        except Exception:  # noqa: BLE001 - unreadable: say so, keep the report
            lines.append(f"| {exp} | unreadable | — | — | — | — |")
            continue
        man = res.manifest(exp)
        status = man.get("status", "no manifest")
        # The commits the chunks were computed at (the manifest's own "git" is
        # the commit at merge time); "modified": uncommitted changes then.
        chunk_git = [
            c.get("git") or {} for c in (man.get("chunks") or {}).values()
        ] or [man.get("git", {}) or {}]
        shas = sorted({str(g.get("commit") or "")[:10] for g in chunk_git} - {""})
        commit = ", ".join(shas) or "—"
        if any(g.get("dirty") for g in chunk_git):
            commit += " (modified)"
        if (man.get("config") or {}).get("smoke"):
            smoke.append(exp)
        files = man.get("problem_files") or {}
        if files and not {str(f.get("source", "built")) for f in files.values()} <= {
            "shipped",
            "generated",
        }:
            unshipped.append(exp)
        n_obj = runs["object"].nunique() if "object" in runs else 0
        t = runs["trial"].nunique() if "trial" in runs else 0
        r = runs["rollout"].nunique() if "rollout" in runs else 0
        h = int(runs["horizon"].max()) if "horizon" in runs and len(runs) else 0
        lines.append(f"| {exp} | {status} | {n_obj} | {t} × {r} | {h} | {commit} |")
    lines += [
        "",
        '"computed at": the git commit(s) the chunks of an experiment ran at; '
        '"(modified)": the working tree also held uncommitted changes then '
        "(each manifest lists every chunk's commit and host).",
        "",
    ]
    if unshipped:
        lines += [
            f"> **Note:** {', '.join(unshipped)} were made from problem files built "
            "on one machine, not from the shipped problem set (`data/problemset/`, "
            "the same bytes on every machine); a build on another processor "
            "differs, so these results can be checked only by recomputing them on "
            "the shipped set (`python -m legs_jax.sweep --all --overwrite`).",
            "",
        ]
    if smoke:
        lines += [
            f"> **Warning:** {', '.join(smoke)} hold smoke-test results (toy "
            "synthetic problems, tiny sizes), not the paper's experiments; none of "
            "their numbers is comparable with the paper.",
            "",
        ]
    incomplete = [
        e
        for e in ctx["experiments"]
        if res.has(e, "runs")
        and res.manifest(e).get("status", "complete") != "complete"
    ]
    if incomplete:
        lines += [
            f"> **Warning:** {', '.join(incomplete)} did not finish; their numbers "
            "cover the finished part only.",
            "",
        ]
    if ctx.get("problems"):
        lines += ["**Missing outputs:**", ""]
        lines += [f"- {p}" for p in ctx["problems"]]
        lines.append("")
    return lines


def appendix_section(ctx: Mapping, spec: Appendix) -> list[str]:
    """The report's lines on one appendix experiment: its table and the best
    setting against the paper's, with whether the grid resolves a ranking."""
    exp, param, paper_best = spec.experiment, spec.param, spec.paper_best
    sweep = ctx.get(exp)
    if sweep is None:
        return [f"_Not available: the `{exp}` results are missing._", ""]
    df = sweep["table"]
    L = [to_markdown(appendix_table(df, spec, sweep["fixed"], sweep["horizon"]))]
    bc = df[df["object"] == "bar_clamp"] if (df["object"] == "bar_clamp").any() else df
    best = bc.loc[bc["mean"].idxmin()]
    sym = _SYMBOL[param]
    spread = float(bc["mean"].max() - bc["mean"].min())
    se_max = float(np.nanmax(bc["se"].to_numpy(float))) if len(bc) else math.nan
    L += [
        f"Best {sym} here: {_param_text(param, best[param])} (gap "
        f"{fmt(float(best['mean']))}); paper: {_param_text(param, paper_best)}. "
        "The spread of the means over the grid is "
        f"{fmt(spread)} against standard errors up to {fmt(se_max)}"
        + (
            ", so the ranking of the settings is not resolved by these runs."
            if spread < 2 * se_max
            else "."
        ),
        "",
    ]
    return L


def build_report(ctx: Mapping) -> str:
    """REPORT.md from what ``legs_jax.report.figures.generate`` computed (``ctx``): the
    results used (of the experiments ``ctx["experiments"]`` names), then the
    sections ``ctx["sections"]`` (position, function of ``ctx``), by position."""
    L: list[str] = [
        "# Reproduction report: LEGS (Fu et al., ICRA 2022)",
        "",
        "Every number below is computed from the saved sweep results by "
        "`python -m legs_jax.figures` and sits beside the paper's; rerunning that "
        "command regenerates this file, the tables in `tables/` and the figures in "
        "`figures/` without rerunning any experiment. The prior of every method is "
        f"**{an.prior_words(an.prior_kind(ctx['results']))}**.",
        "",
    ]
    L += _results_section(ctx)
    for _, section in sorted(ctx["sections"], key=lambda x: x[0]):
        L += section(ctx)
    return "\n".join(L).rstrip("\n") + "\n"
