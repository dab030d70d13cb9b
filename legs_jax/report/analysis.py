"""Numbers of the paper's tables and figures from saved results.

Every function here is a pure function of the tidy tables a sweep writes
(``runs``, ``curves``, ``checks``, ``active_set``, ``grasps``; see
``legs_jax.results``): no I/O, no plotting, no randomness. The paper's own numbers
are kept with the experiment they belong to (``experiments/<name>/analysis.py``).

Aggregation: per object, the mean over its T x R runs; per data set, the
mean and standard error across objects. Standard errors are sample standard
deviations (ddof = 1) divided by the square root of the count; NaN for one value.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from legs_jax.core import verify
from legs_jax.core.constants import DELTA_STOP
from legs_jax.results import hparam_columns

__all__ = [
    "BOUNDS",
    "SET_LABELS",
    "WIN_TOLERANCE",
    "AnalysisError",
    "Arms",
    "active_set_trace",
    "oracle_methods",
    "bound_summary",
    "curve_summary",
    "first_rollout",
    "learning_curves",
    "object_gaps",
    "order_sets",
    "select_arm",
    "stopping_sensitivity",
    "sweep_table",
    "table_one",
    "win_counts",
    "winners",
]


@dataclasses.dataclass(frozen=True, eq=False)
class Arms:
    """How an experiment orders, labels and compares its arms: its declarations,
    which an experiment's analysis passes to the functions here (the library
    knows no experiment).

    ``order`` is Table I's column order (the registry's other methods follow, a
    user's method included); ``declared`` the methods the experiment runs;
    ``variants`` maps (method, variant) to the variant's ``label``,
    ``short_label`` and ``style`` (a method's own are on its card);
    ``proposed`` the method the paper proposes (the subject of the win counts).
    """

    order: tuple[str, ...] = ()
    declared: tuple[str, ...] = ()
    variants: Mapping[tuple[str, str], Mapping[str, Any]] = dataclasses.field(
        default_factory=dict
    )
    proposed: str = ""

    @property
    def methods(self) -> tuple[str, ...]:
        """Every method in table order: ``order``, then the registry's others."""
        from legs_jax.core import methods  # jax: kept out of the figures' start-up

        return tuple(self.order) + tuple(
            m for m in methods.names() if m not in self.order
        )

    @property
    def rivals(self) -> tuple[str, ...]:
        """Every declared method but an oracle row, in table order: the
        competitors and the extra rows (for win counts among all rows)."""
        from legs_jax.core import methods  # jax: kept out of the figures' start-up

        return tuple(
            m
            for m in self.methods
            if m in self.declared
            and m in methods.names()
            and not methods.get(m).card.oracle
        )

    @property
    def competitors(self) -> tuple[str, ...]:
        """Methods compared for a "win": the :attr:`rivals` of ``order`` (not an
        oracle row such as the K=100 upper bound); extra rows (Bayes-UCB, a
        user's method) are shown but do not compete, so the counts keep the
        paper's definition."""
        return tuple(m for m in self.rivals if m in self.order)

    def declaration(self, method: str, variant: str = "") -> dict:
        """``label``, ``short_label`` and ``style`` of an arm: a declared
        variant's, else its method's (:mod:`legs_jax.core.methods`); empty for an
        unknown method."""
        from legs_jax.core import methods  # jax: kept out of the figures' start-up

        if (method, variant) in self.variants:
            return dict(self.variants[(method, variant)])
        if variant or method not in methods.names():
            return {}
        card = methods.get(method).card
        return dict(
            label=card.label, short_label=card.short_label, style=dict(card.style)
        )

    def label(self, method: str, variant: str = "") -> str:
        """Display name of an arm (its declared label); an unknown variant is
        shown in brackets after its method's label."""
        label = self.declaration(method, variant).get("label")
        if label:
            return label
        base = self.declaration(method).get("label") or method
        return f"{base} [{variant}]" if variant else base

    def rank(self, method: str, variant: str) -> tuple[int, int, str]:
        order = self.methods
        m = order.index(method) if method in order else len(order)
        return (m, 0 if variant == "" else 1, variant)

    def sort(self, arms: Iterable[tuple[str, str]]) -> list[tuple[str, str]]:
        """(method, variant) pairs, unique, in table order (variants after their
        method's default)."""
        return sorted(set(arms), key=lambda a: (self.rank(*a), a[0]))

    def of_table(self, df: pd.DataFrame) -> list[tuple[str, str]]:
        """The arms present in a table with ``method`` and ``variant`` columns."""
        return self.sort(zip(df["method"], df["variant"], strict=True))


WIN_TOLERANCE = 0.005
SET_LABELS = {"dexnet_adv": "Dex-Net Adversarial", "egad_eval": "EGAD! evaluation"}

# Lower bounds of the stopping rule: name -> checks column. "all" is the paper's
# formula (p-hat* over all candidates), "attempted" the variant over attempted
# grasps only, "ours" the Dirichlet bound on an empirical-Bayes posterior
# of the recommended grasps (legs_jax.core.stopping).
BOUNDS = {"all": "p_lower", "attempted": "p_lower_attempted", "ours": "p_lower_eb"}

_RUN_KEYS = ["object", "trial", "rollout"]


# The prior the problems of a sweep carry (its manifests' "priors"), in words.
PRIOR_WORDS = {
    "learned": "learned (a small GQ-CNN-style network trained on generated objects "
    "only, never on these)",
    "synthetic": "synthetic (a stand-in for GQ-CNN made from p with seeded noise)",
}


def prior_kind(res: Any, experiment: str = "main") -> str:
    """The prior of an experiment's problems, from its manifest (``res``: a
    :class:`legs_jax.report.figures.Results`): "learned", "synthetic", several joined
    by "+", or "unknown" (results from before the manifests said)."""
    kinds = res.manifest(experiment).get("priors") or []
    return "+".join(kinds) if kinds else "unknown"


def prior_words(kind: str) -> str:
    return PRIOR_WORDS.get(kind, kind)


class AnalysisError(ValueError):
    """The results cannot give the requested number (missing column, no rows,
    ambiguous configuration); the message says which."""


# ------------------------------------------------------------------------ helpers
def oracle_methods() -> tuple[str, ...]:
    """The registered methods that are oracle rows (never compared or bolded)."""
    from legs_jax.core import methods  # jax: kept out of the figures' start-up

    return tuple(m for m in methods.names() if methods.get(m).card.oracle)


def _require(df: pd.DataFrame, columns: Iterable[str], what: str) -> None:
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise AnalysisError(f"{what} lacks the column(s) {', '.join(missing)}")


def _se(values: np.ndarray) -> float:
    values = np.asarray(values, np.float64)
    if values.size < 2:
        return float("nan")
    return float(values.std(ddof=1) / np.sqrt(values.size))


def order_sets(sets: Iterable[str]) -> list[str]:
    """The paper's sets first (Dex-Net, EGAD), then any other set by name."""
    sets = list(dict.fromkeys(sets))
    known = [s for s in SET_LABELS if s in sets]
    return known + sorted(s for s in sets if s not in SET_LABELS)


def select_arm(
    df: pd.DataFrame,
    method: str,
    variant: str = "",
    *,
    vary: Sequence[str] = (),
    **hparams: float,
) -> pd.DataFrame:
    """Rows of one arm (and, if given, hyperparameter values); refuses rows that
    hold several settings of the hyperparameters not named in ``vary``."""
    _require(df, ["method", "variant"], "the table")
    sel = (df["method"] == method) & (df["variant"] == variant)
    for name, value in hparams.items():
        _require(df, [name], "the table")
        sel &= np.isclose(df[name].to_numpy(np.float64), float(value))
    out = df.loc[sel]
    hp = [c for c in hparam_columns() if c in out.columns and c not in vary]
    if hp and len(out) and len(out[hp].drop_duplicates()) > 1:
        raise AnalysisError(
            f"rows of {method!r} (variant {variant!r}) hold several hyperparameter "
            f"settings; select one"
        )
    return out


# ------------------------------------------------------------------------ Table I
def object_gaps(runs: pd.DataFrame, arms: Arms) -> pd.DataFrame:
    """Per object and arm: mean and standard error of the final gap over its runs.

    Returns columns ``set, object, method, variant, n_runs, gap_mean, gap_se``,
    sets in ``order_sets`` order, objects in order of first appearance, arms in
    Table I order.
    """
    _require(
        runs,
        ["set", "object", "method", "variant", "final_gap"],
        "runs.parquet",
    )
    if runs.empty:
        raise AnalysisError("runs.parquet has no rows")
    hp = [c for c in hparam_columns() if c in runs.columns]
    if hp:
        n_cfg = runs.groupby(["object", "method", "variant"], sort=False)[hp].apply(
            lambda g: len(g.drop_duplicates())
        )
        multi = n_cfg[n_cfg > 1]
        if len(multi):
            obj, method, variant = multi.index[0]
            raise AnalysisError(
                f"runs of {method!r} (variant {variant!r}) on {obj!r} hold several "
                "hyperparameter settings; Table I needs one per arm"
            )
    rows = []
    for (set_, obj, method, variant), g in runs.groupby(
        ["set", "object", "method", "variant"], sort=False
    ):
        v = g["final_gap"].to_numpy(np.float64)
        rows.append((set_, obj, method, variant, v.size, float(v.mean()), _se(v)))
    out = pd.DataFrame(
        rows,
        columns=["set", "object", "method", "variant", "n_runs", "gap_mean", "gap_se"],
    )
    set_rank = {s: i for i, s in enumerate(order_sets(out["set"]))}
    obj_rank = {o: i for i, o in enumerate(dict.fromkeys(runs["object"]))}
    key = pd.DataFrame(
        {
            "s": out["set"].map(set_rank),
            "o": out["object"].map(obj_rank),
            "a": [
                arms.rank(m, v)
                for m, v in zip(out["method"], out["variant"], strict=True)
            ],
        }
    )
    idx = sorted(range(len(out)), key=lambda i: (key["s"][i], key["o"][i], key["a"][i]))
    return out.iloc[idx].reset_index(drop=True)


def table_one(gaps: pd.DataFrame, arms: Arms) -> pd.DataFrame:
    """Table I from ``object_gaps``: per set and arm, the mean and standard error
    across objects of the per-object mean final gap.

    Returns columns ``set, method, variant, n_objects, mean, se``.
    """
    rows = []
    for set_ in order_sets(gaps["set"]):
        g = gaps[gaps["set"] == set_]
        for method, variant in arms.of_table(g):
            v = g.loc[
                (g["method"] == method) & (g["variant"] == variant), "gap_mean"
            ].to_numpy(np.float64)
            rows.append((set_, method, variant, v.size, float(v.mean()), _se(v)))
    return pd.DataFrame(
        rows, columns=["set", "method", "variant", "n_objects", "mean", "se"]
    )


def winners(
    gaps: pd.DataFrame,
    competitors: Sequence[str],
    tolerance: float = WIN_TOLERANCE,
) -> pd.DataFrame:
    """Per object, which methods "win": a method wins an object when its mean final
    gap is at most every other competitor's + ``tolerance``.

    Only default-configuration arms (variant "") compete. Objects lacking any
    competitor are left out. An object on which every competitor is within noise
    of the best (each mean within two combined standard errors of the best one's,
    ``gap_se`` of ``gaps``) has no winner: its column ``within_noise`` is True and
    every competitor's False. Returns ``set, object``, one bool column per
    competitor, and ``within_noise``.
    """
    base = gaps[(gaps["variant"] == "") & gaps["method"].isin(competitors)]
    wide = base.pivot_table(
        index=["set", "object"], columns="method", values="gap_mean", sort=False
    )
    wide = wide.dropna(axis=0, how="any")
    missing = [m for m in competitors if m not in wide.columns]
    if missing or wide.empty:
        return pd.DataFrame(columns=["set", "object", *competitors, "within_noise"])
    vals = wide[list(competitors)].to_numpy(np.float64)  # [O, M]
    noise = np.zeros(len(wide), bool)
    if "gap_se" in base.columns and len(competitors) > 1:
        se = (
            base.pivot_table(
                index=["set", "object"], columns="method", values="gap_se", sort=False
            )
            .reindex(index=wide.index, columns=list(competitors))
            .to_numpy(np.float64)
        )
        best = vals.argmin(axis=1)
        rows = np.arange(len(vals))
        combined = np.sqrt(se**2 + se[rows, best][:, None] ** 2)
        close = vals - vals[rows, best][:, None] <= 2.0 * combined
        noise = close.all(axis=1)  # a NaN standard error is never within noise
    out = wide.index.to_frame(index=False)
    for j, m in enumerate(competitors):
        others = np.delete(vals, j, axis=1).min(axis=1)
        out[m] = (vals[:, j] <= others + tolerance) & ~noise
    out["within_noise"] = noise
    return out


def win_counts(
    gaps: pd.DataFrame,
    competitors: Sequence[str],
    tolerance: float = WIN_TOLERANCE,
) -> pd.DataFrame:
    """Wins per set and competitor: ``set, method, wins, n_objects`` (objects that
    have every competitor), with ``n_total`` the objects of the set in ``gaps``."""
    w = winners(gaps, competitors, tolerance)
    rows = []
    for set_ in order_sets(gaps["set"]):
        n_total = int(gaps.loc[gaps["set"] == set_, "object"].nunique())
        ws = w[w["set"] == set_]
        for m in competitors:
            wins = int(ws[m].sum()) if len(ws) else 0
            rows.append((set_, m, wins, len(ws), n_total))
    return pd.DataFrame(rows, columns=["set", "method", "wins", "n_objects", "n_total"])


# ------------------------------------------------------------------ early stopping
def _bound_columns(checks: pd.DataFrame) -> dict[str, str]:
    """Bounds present in ``checks`` (a column with at least one finite value)."""
    out = {}
    for name, col in BOUNDS.items():
        if col in checks.columns and np.isfinite(checks[col].to_numpy(float)).any():
            out[name] = col
    return out


def bound_summary(checks: pd.DataFrame, by_object: bool = False) -> pd.DataFrame:
    """Accuracy and tightness of the stopping bound.

    Accuracy: fraction of checks with lower bound <= true performance. Tightness:
    mean of (true performance - lower bound) over checks. Pooled over every check
    (``by_object=False``) or per object. Returns ``bound`` ("all" = the paper's
    formula, "attempted" = over attempted grasps), optionally ``object``,
    ``n_checks``, ``accuracy``, ``tightness``.
    """
    _require(checks, ["object", "step", "true_performance"], "checks.parquet")
    cols = _bound_columns(checks)
    if not cols or checks.empty:
        raise AnalysisError("checks.parquet has no Dirichlet checks")
    rows = []
    for name, col in cols.items():
        d = checks[["object", "true_performance", col]].dropna()
        groups = d.groupby("object", sort=False) if by_object else [(None, d)]
        for obj, g in groups:
            lo = g[col].to_numpy(np.float64)
            tp = g["true_performance"].to_numpy(np.float64)
            row = {"bound": name}
            if by_object:
                row["object"] = obj
            row.update(
                n_checks=lo.size,
                accuracy=float(np.mean(lo <= tp)),
                tightness=float(np.mean(tp - lo)),
            )
            rows.append(row)
    return pd.DataFrame(rows)


def _checks_matrix(checks: pd.DataFrame, col: str, *more: str):
    """(bound [runs, checks], true performance [runs, checks], check steps) of
    one bound column, runs in the order of ``_RUN_KEYS``; then a [runs, checks]
    matrix of each of ``more`` in the same order (NaN where missing)."""
    lo = checks.pivot_table(
        index=_RUN_KEYS, columns="step", values=col, aggfunc="first"
    )
    aligned = [
        checks.pivot_table(
            index=_RUN_KEYS, columns="step", values=c, aggfunc="first", dropna=False
        )
        .reindex(index=lo.index, columns=lo.columns)
        .to_numpy(np.float64)
        for c in ("true_performance", *more)
    ]
    steps = lo.columns.to_numpy(np.int64)
    return lo.to_numpy(np.float64), aligned[0], steps, *aligned[1:]


def _stop_row(
    bound: str, rho: float, stopped, stop_step, truth, **extra
) -> dict[str, Any]:
    """One row of the stopping tables: ``truth`` [stopped runs] at their stop."""
    n_runs, n_stop = len(stopped), int(np.sum(stopped))
    return dict(
        bound=bound,
        rho_min=float(rho),
        n_runs=n_runs,
        n_stopped=n_stop,
        frac_stopped=n_stop / n_runs if n_runs else float("nan"),
        accuracy=float(np.mean(truth >= rho)) if n_stop else float("nan"),
        mean_stop_step=float(np.mean(stop_step)),
        se_stop_step=_se(stop_step),
        **extra,
    )


# The stopping rule that tests before it stops (legs_jax.core.verify), on our bound.
VERIFIED = "verified"


def verified_stopping(
    checks: pd.DataFrame,
    rho_min: Sequence[float],
    horizon: int,
    seed: int = 0,
    delta: float = DELTA_STOP,
) -> pd.DataFrame:
    """Verified stopping against the threshold rho_min, replayed on the runs'
    checks (:func:`legs_jax.core.verify.simulate_stops`): at a check where our
    bound reaches rho_min the recommendations are frozen and tested by attempts
    whose outcomes are drawn from their true performance (as the environment
    draws every outcome), with a generator seeded by ``seed`` and rho_min, so the
    rows are reproducible. Rows as :func:`stopping_sensitivity`'s (``bound`` is
    ``"verified"``), plus ``mean_attempts``: verification attempts per run."""
    _require(checks, [*_RUN_KEYS, "step", "true_performance"], "checks.parquet")
    col = BOUNDS["ours"]
    if col not in checks.columns or not np.isfinite(checks[col].to_numpy(float)).any():
        raise AnalysisError("checks.parquet has no checks of our bound")
    after, recorded = None, 0.0
    if "after_failure" in checks.columns:
        L, V, steps, after = _checks_matrix(checks, col, "after_failure")
        recorded = float(np.mean(~np.isnan(after)))
    else:
        L, V, steps = _checks_matrix(checks, col)
    rows = []
    for rho in rho_min:
        rng = np.random.default_rng([seed, int(round(1000 * rho))])
        r = verify.simulate_stops(
            L, V, steps, float(rho), horizon, rng, delta, after=after
        )
        stopped = r["stopped"]
        rows.append(
            _stop_row(
                VERIFIED,
                rho,
                stopped,
                r["stop_step"],
                r["truth"][stopped],
                mean_attempts=float(r["attempts"].mean()),
                after_recorded=recorded,
            )
        )
    return pd.DataFrame(rows)


def stopping_sensitivity(
    checks: pd.DataFrame, rho_min: Sequence[float], horizon: int
) -> pd.DataFrame:
    """Early stopping against the threshold rho_min (Fig. 4).

    Each run (object, trial, rollout) stops at its first check whose lower bound
    is >= rho_min. Accuracy is the fraction of stopped runs whose true performance
    at that check is >= rho_min (NaN when none stopped); the stopping step is
    ``horizon`` for a run that never stops. Returns ``bound, rho_min, n_runs,
    n_stopped, frac_stopped, accuracy, mean_stop_step, se_stop_step``.
    """
    _require(checks, [*_RUN_KEYS, "step", "true_performance"], "checks.parquet")
    cols = _bound_columns(checks)
    if not cols or checks.empty:
        raise AnalysisError("checks.parquet has no Dirichlet checks")
    rows = []
    for name, col in cols.items():
        L, V, steps = _checks_matrix(checks, col)
        for rho in rho_min:
            hit = np.nan_to_num(L, nan=-np.inf) >= rho
            stopped = hit.any(axis=1)
            first = hit.argmax(axis=1)
            stop_step = np.where(stopped, steps[first], horizon).astype(np.float64)
            perf = V[np.arange(len(V)), first][stopped]
            rows.append(_stop_row(name, rho, stopped, stop_step, perf))
    return pd.DataFrame(rows)


# ------------------------------------------------------------- appendix sweeps
def sweep_table(runs: pd.DataFrame, param: str) -> pd.DataFrame:
    """Final gap against one swept hyperparameter (the appendix tables).

    Per object and value of ``param``: ``n_runs``, ``mean`` and ``se`` of the final
    gap over the runs (one object, so the standard error is over its T x R runs).
    Returns ``object, <param>, n_runs, mean, se`` sorted by object and value.
    """
    _require(runs, ["object", param, "final_gap"], "runs.parquet")
    if runs.empty:
        raise AnalysisError("runs.parquet has no rows")
    rows = []
    for (obj, value), g in runs.groupby(["object", param], sort=True):
        v = g["final_gap"].to_numpy(np.float64)
        rows.append((obj, float(value), v.size, float(v.mean()), _se(v)))
    return pd.DataFrame(rows, columns=["object", param, "n_runs", "mean", "se"])


# ---------------------------------------------------------------- case study
def learning_curves(curves: pd.DataFrame, obj: str, arms: Arms) -> pd.DataFrame:
    """Learning curves of every arm on one object: ``method, variant, step,
    gap_mean, gap_se, n_runs`` in Table I arm order and step order."""
    _require(
        curves,
        ["object", "method", "variant", "step", "gap_mean", "gap_se"],
        "curves.parquet",
    )
    c = curves[curves["object"] == obj]
    out = []
    for method, variant in arms.of_table(c):
        g = select_arm(c, method, variant).sort_values("step")
        out.append(g)
    if not out:
        return c.iloc[0:0]
    cols = ["method", "variant", "step", "gap_mean", "gap_se"]
    if "n_runs" in c.columns:
        cols.append("n_runs")
    return pd.concat(out, ignore_index=True)[cols]


def curve_summary(lc: pd.DataFrame) -> pd.DataFrame:
    """Per arm of ``learning_curves`` output: ``final`` (gap at the last step) and
    ``area`` (mean gap over the run: trapezoid area under the curve over its step
    range; lower means faster convergence)."""
    rows = []
    for (method, variant), g in lc.groupby(["method", "variant"], sort=False):
        x = g["step"].to_numpy(np.float64)
        y = g["gap_mean"].to_numpy(np.float64)
        span = x[-1] - x[0]
        area = (
            float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)) / span) if span else y[0]
        )
        rows.append((method, variant, float(y[-1]), area))
    return pd.DataFrame(rows, columns=["method", "variant", "final", "area"])


def first_rollout(active_set: pd.DataFrame, method: str) -> pd.DataFrame:
    """The rows of ``method``'s first grid point, trial and rollout (the one
    rollout whose active sets are recorded)."""
    a = active_set
    if "method" in a.columns:
        a = a[a["method"] == method]
    if "grid_index" in a.columns and len(a):
        a = a[a["grid_index"] == a["grid_index"].min()]
    for c in ("trial", "rollout"):
        if c in a.columns and len(a):
            a = a[a[c] == a[c].min()]
    return a


def active_set_trace(
    active_set: pd.DataFrame,
    obj: str,
    method: str,
    pose: int | None = None,
    grasps: pd.DataFrame | None = None,
) -> tuple[int, pd.DataFrame, pd.DataFrame]:
    """The active set of one rollout of ``method`` on one pose over time (Fig. 1,
    bottom; :func:`first_rollout`).

    ``pose`` defaults to the pose whose active set changed most (most distinct
    members over the run) among the poses present at no fewer than half as many
    checks as the most present one (ties: more checks, then the most likely
    landing pose when ``grasps`` gives landing probabilities, then the lowest
    index). Returns (pose, members, summary): members has one row per
    filled slot and check (``step, slot, grasp, robustness``); summary one row
    per check: ``step, n_members, best, mean``, plus ``p_star`` (best robustness
    of the pose's reservoir) when ``grasps`` is given.
    """
    _require(active_set, ["object", "step", "pose", "slot", "robustness"], "active_set")
    a = first_rollout(active_set[active_set["object"] == obj], method)
    if a.empty:
        raise AnalysisError(f"active_set.parquet has no {method} rows for {obj!r}")
    if pose is None:
        n_checks = a.groupby("pose")["step"].nunique()
        landing = pd.Series(0.0, index=n_checks.index)
        if grasps is not None and "landing" in grasps.columns:
            g = grasps[grasps["object"] == obj]
            lam = g.groupby("pose")["landing"].first()
            landing = lam.reindex(n_checks.index).fillna(0.0)
        if "grasp" in a.columns:
            distinct = a.groupby("pose")["grasp"].nunique()
        else:
            distinct = pd.Series(0, index=n_checks.index)
        eligible = [p for p in n_checks.index if 2 * n_checks[p] >= n_checks.max()]
        key = sorted(
            eligible,
            key=lambda p: (-distinct[p], -n_checks[p], -landing[p], int(p)),
        )
        pose = int(key[0])
    m = a[a["pose"] == pose].sort_values(["step", "slot"])
    cols = [c for c in ("step", "slot", "grasp", "robustness") if c in m.columns]
    members = m[cols].reset_index(drop=True)
    summary = (
        members.groupby("step")["robustness"]
        .agg(n_members="size", best="max", mean="mean")
        .reset_index()
    )
    if grasps is not None:
        g = grasps[(grasps["object"] == obj) & (grasps["pose"] == pose)]
        if "trial" in g.columns and len(g):
            g = g[g["trial"] == g["trial"].min()]
        if len(g):
            summary["p_star"] = float(g["robustness"].max())
    return pose, members, summary
