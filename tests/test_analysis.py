"""Numbers of the tables and figures (legs_jax.report.analysis), checked against
aggregates computed here independently, and against small hand-made cases."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from results_fixture import make_results

import experiments
from experiments.main.analysis import ARMS
from legs_jax.report import analysis as an


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return make_results(tmp_path_factory.mktemp("analysis") / "results")


@pytest.fixture(scope="module")
def main_runs(results):
    return pd.read_parquet(results / "main" / "runs.parquet")


def _plain_object_means(runs: pd.DataFrame) -> dict:
    """(object, method, variant) -> (mean, se, n) with plain Python loops."""
    acc: dict = {}
    for o, m, v, g in zip(
        runs["object"], runs["method"], runs["variant"], runs["final_gap"], strict=True
    ):
        acc.setdefault((o, m, v), []).append(float(g))
    out = {}
    for k, vals in acc.items():
        n = len(vals)
        mean = sum(vals) / n
        var = sum((x - mean) ** 2 for x in vals) / (n - 1)
        out[k] = (mean, math.sqrt(var / n), n)
    return out


def test_object_gaps_match_plain_means(main_runs):
    gaps = an.object_gaps(main_runs, ARMS)
    plain = _plain_object_means(main_runs)
    assert len(gaps) == len(plain)
    for r in gaps.itertuples():
        mean, se, n = plain[(r.object, r.method, r.variant)]
        assert r.n_runs == n
        assert r.gap_mean == pytest.approx(mean, abs=1e-12)
        assert r.gap_se == pytest.approx(se, abs=1e-12)


def test_table_one_matches_plain_aggregation(main_runs):
    gaps = an.object_gaps(main_runs, ARMS)
    t1 = an.table_one(gaps, ARMS)
    plain = _plain_object_means(main_runs)
    set_of = dict(zip(main_runs["object"], main_runs["set"], strict=True))
    per_set: dict = {}
    for (o, m, v), (mean, _, _) in plain.items():
        per_set.setdefault((set_of[o], m, v), []).append(mean)
    n_arms = len(experiments.get("main").ARMS)
    assert len(t1) == len(per_set) == 2 * n_arms
    for r in t1.itertuples():
        vals = np.array(per_set[(r.set, r.method, r.variant)])
        assert r.n_objects == len(vals)
        assert r.mean == pytest.approx(vals.mean(), abs=1e-12)
        assert r.se == pytest.approx(vals.std(ddof=1) / np.sqrt(len(vals)), abs=1e-12)
    # Paper's sets first, arms in the paper's column order with the variant last
    # among BORGES (K=2000).
    assert list(dict.fromkeys(t1["set"])) == ["dexnet_adv", "egad_eval"]
    arms = list(zip(t1["method"], t1["variant"], strict=True))[:8]
    assert arms[:5] == [
        ("dexnet", ""),
        ("tql", ""),
        ("borges_100", ""),
        ("k100_ub", ""),
        ("borges_2000", ""),
    ]
    assert arms[5] == ("borges_2000", "orig_prior")


def _gaps(rows):
    return pd.DataFrame(
        rows, columns=["set", "object", "method", "variant", "gap_mean"]
    ).assign(n_runs=100, gap_se=0.01)


def _all_methods(set_, obj, values, variant_extra=None):
    rows = [(set_, obj, m, "", values[m]) for m in ARMS.methods if m in values]
    if variant_extra is not None:
        rows.append((set_, obj, "borges_2000", "orig_prior", variant_extra))
    return rows


def test_win_rule_tolerance_oracle_and_variants():
    base = dict(
        dexnet=0.6, tql=0.3, borges_100=0.2, k100_ub=0.01, borges_2000=0.1,
        legs_no_as=0.25, legs=0.1,
    )  # fmt: skip
    rows = []
    # o1: LEGS 0.004 worse than BORGES-2000 -> both win (within 0.005).
    rows += _all_methods("dexnet_adv", "o1", {**base, "legs": 0.104})
    # o2: LEGS 0.006 worse -> only BORGES-2000 wins.
    rows += _all_methods("dexnet_adv", "o2", {**base, "legs": 0.106})
    # o3: LEGS best; the oracle row and a better variant do not count.
    rows += _all_methods("dexnet_adv", "o3", {**base, "legs": 0.05}, variant_extra=0.0)
    # o4: TQL best by far.
    rows += _all_methods("egad_eval", "o4", {**base, "tql": 0.0})
    gaps = _gaps(rows)
    w = an.winners(gaps, ARMS.competitors).set_index("object")
    assert w.loc["o1", "legs"] and w.loc["o1", "borges_2000"]
    assert not w.loc["o2", "legs"] and w.loc["o2", "borges_2000"]
    assert w.loc["o3", "legs"] and not w.loc["o3", "borges_2000"]
    assert w.loc["o4", "tql"] and not w.loc["o4", "legs"]
    assert "k100_ub" not in w.columns
    wc = an.win_counts(gaps, ARMS.competitors).set_index(["set", "method"])
    assert wc.loc[("dexnet_adv", "legs"), "wins"] == 2
    assert wc.loc[("dexnet_adv", "legs"), "n_objects"] == 3
    assert wc.loc[("dexnet_adv", "borges_2000"), "wins"] == 2
    assert wc.loc[("egad_eval", "tql"), "wins"] == 1
    assert wc.loc[("egad_eval", "legs"), "wins"] == 0


def test_win_counts_skip_objects_missing_a_method():
    base = dict(
        dexnet=0.6, tql=0.3, borges_100=0.2, k100_ub=0.01, borges_2000=0.1,
        legs_no_as=0.25, legs=0.05,
    )  # fmt: skip
    rows = _all_methods("dexnet_adv", "full", base)
    rows += [r for r in _all_methods("dexnet_adv", "partial", base) if r[2] != "tql"]
    wc = an.win_counts(_gaps(rows), ARMS.competitors).set_index(["set", "method"])
    assert wc.loc[("dexnet_adv", "legs"), "n_objects"] == 1
    assert wc.loc[("dexnet_adv", "legs"), "n_total"] == 2


def test_win_counts_on_fixture_match_independent_rule(main_runs):
    plain = _plain_object_means(main_runs)
    set_of = dict(zip(main_runs["object"], main_runs["set"], strict=True))
    expected: dict = {}
    for o in set_of:
        legs = plain[(o, "legs", "")][0]
        others = [plain[(o, m, "")][0] for m in ARMS.competitors if m != "legs"]
        expected[set_of[o]] = expected.get(set_of[o], 0) + int(
            all(legs <= x + 0.005 for x in others)
        )
    wc = an.win_counts(an.object_gaps(main_runs, ARMS), ARMS.competitors)
    got = wc[wc["method"] == "legs"].set_index("set")["wins"].to_dict()
    assert got == expected


def test_object_gaps_refuses_mixed_hyperparameters(main_runs):
    runs = main_runs.copy()
    sel = (runs["method"] == "legs") & (runs["trial"] == 0)
    runs.loc[sel, "delta"] = 0.1
    with pytest.raises(an.AnalysisError, match="several hyperparameter"):
        an.object_gaps(runs, ARMS)


def test_missing_column_is_named(main_runs):
    with pytest.raises(an.AnalysisError, match="final_gap"):
        an.object_gaps(main_runs.drop(columns=["final_gap"]), ARMS)


def _checks(rows):
    return pd.DataFrame(
        rows,
        columns="object trial rollout step p_lower p_lower_attempted "
        "true_performance".split(),
    )


def test_bound_summary_by_hand():
    c = _checks(
        [
            ("a", 0, 0, 100, 0.50, 0.40, 0.60),
            ("a", 0, 0, 200, 0.70, 0.60, 0.65),  # bound above truth
            ("b", 0, 0, 100, 0.10, 0.05, 0.30),
            ("b", 0, 0, 200, 0.20, 0.10, 0.30),
        ]
    )
    s = an.bound_summary(c).set_index("bound")
    assert s.loc["all", "n_checks"] == 4
    assert s.loc["all", "accuracy"] == pytest.approx(0.75)
    assert s.loc["all", "tightness"] == pytest.approx((0.1 - 0.05 + 0.2 + 0.1) / 4)
    assert s.loc["attempted", "accuracy"] == pytest.approx(1.0)
    assert s.loc["attempted", "tightness"] == pytest.approx(
        (0.2 + 0.05 + 0.25 + 0.2) / 4
    )
    per = an.bound_summary(c, by_object=True)
    a = per[(per["bound"] == "all") & (per["object"] == "a")].iloc[0]
    assert a["accuracy"] == pytest.approx(0.5)


def test_bound_summary_without_attempted_variant():
    c = _checks([("a", 0, 0, 100, 0.5, np.nan, 0.6)])
    s = an.bound_summary(c)
    assert list(s["bound"]) == ["all"]


def test_stopping_sensitivity_by_hand():
    c = _checks(
        [
            # run 1 crosses 0.5 at 200 (true 0.55: correct), 0.7 never
            ("a", 0, 0, 100, 0.30, 0.30, 0.40),
            ("a", 0, 0, 200, 0.55, 0.50, 0.55),
            ("a", 0, 0, 300, 0.60, 0.60, 0.62),
            # run 2 crosses 0.5 at 100 with true 0.45: wrong
            ("a", 0, 1, 100, 0.52, 0.20, 0.45),
            ("a", 0, 1, 200, 0.58, 0.30, 0.60),
            ("a", 0, 1, 300, 0.72, 0.40, 0.75),
        ]
    )
    s = an.stopping_sensitivity(c, [0.5, 0.7, 0.9], horizon=3000)
    a = s[s["bound"] == "all"].set_index("rho_min")
    assert a.loc[0.5, "n_stopped"] == 2
    assert a.loc[0.5, "accuracy"] == pytest.approx(0.5)
    assert a.loc[0.5, "mean_stop_step"] == pytest.approx(150.0)
    assert a.loc[0.7, "n_stopped"] == 1
    assert a.loc[0.7, "accuracy"] == pytest.approx(1.0)
    assert a.loc[0.7, "mean_stop_step"] == pytest.approx((3000 + 300) / 2)
    assert a.loc[0.9, "n_stopped"] == 0
    assert math.isnan(a.loc[0.9, "accuracy"])
    assert a.loc[0.9, "mean_stop_step"] == 3000
    assert a.loc[0.9, "frac_stopped"] == 0.0
    att = s[s["bound"] == "attempted"].set_index("rho_min")
    assert att.loc[0.5, "n_stopped"] == 1
    assert att.loc[0.5, "mean_stop_step"] == pytest.approx((200 + 3000) / 2)


def test_sweep_table_matches_groupby(results):
    runs = pd.read_parquet(results / "prior_strength" / "runs.parquet")
    t = an.sweep_table(runs, "s")
    assert list(t["s"]) == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    for r in t.itertuples():
        v = runs.loc[np.isclose(runs["s"], r.s), "final_gap"].to_numpy()
        assert r.n_runs == len(v)
        assert r.mean == pytest.approx(v.mean(), abs=1e-12)
        assert r.se == pytest.approx(v.std(ddof=1) / np.sqrt(len(v)), abs=1e-12)


def test_active_set_trace(results):
    act = pd.read_parquet(results / "case_study" / "active_set.parquet")
    grasps = pd.read_parquet(results / "case_study" / "grasps.parquet")
    pose, members, summary = an.active_set_trace(act, "C3", "legs", grasps=grasps)
    # The pose whose active set changed most, among the poses present at half
    # the checks or more; ties: more checks, likelier landing, lower index.
    c3 = act[(act["object"] == "C3") & (act["trial"] == 0) & (act["rollout"] == 0)]
    g = grasps[grasps["object"] == "C3"].groupby("pose")["landing"].first()
    stats = {
        int(p): (d["grasp"].nunique(), d["step"].nunique(), g.get(p, 0.0))
        for p, d in c3.groupby("pose")
    }
    most = max(v[1] for v in stats.values())
    expected = min(
        (p for p, v in stats.items() if 2 * v[1] >= most),
        key=lambda p: (-stats[p][0], -stats[p][1], -stats[p][2], p),
    )
    assert pose == expected
    rows = act[(act["object"] == "C3") & (act["pose"] == pose)]
    assert len(members) == len(rows)
    for r in summary.itertuples():
        v = rows.loc[rows["step"] == r.step, "robustness"]
        assert r.best == pytest.approx(v.max())
        assert r.mean == pytest.approx(v.mean())
        assert r.n_members == len(v)
    p_star = grasps[(grasps["object"] == "C3") & (grasps["pose"] == pose)][
        "robustness"
    ].max()
    assert summary["p_star"].iloc[0] == pytest.approx(p_star)
    assert (summary["best"] <= p_star + 1e-12).all()
    with pytest.raises(an.AnalysisError, match="no legs rows"):
        an.active_set_trace(act, "no_such_object", "legs")


def test_learning_curves_order_and_arms(results):
    curves = pd.read_parquet(results / "case_study" / "curves.parquet")
    lc = an.learning_curves(curves, "F6", ARMS)
    arms = list(dict.fromkeys(zip(lc["method"], lc["variant"], strict=True)))
    assert [m for m, _ in arms] == [m for m in ARMS.methods if m in set(curves.method)]
    assert len(arms) == len(experiments.get("case_study").ARMS)
    for _, g in lc.groupby(["method", "variant"]):
        assert np.all(np.diff(g["step"].to_numpy()) > 0)


def test_curve_summary_area_and_final():
    steps = np.arange(0, 101, 10)
    lc = pd.DataFrame(
        {
            "method": ["legs"] * 11 + ["dexnet"] * 11,
            "variant": [""] * 22,
            "step": np.concatenate([steps, steps]),
            # LEGS falls linearly from 0.5 to 0.0; Dex-Net stays at 0.4.
            "gap_mean": np.concatenate([0.5 - 0.005 * steps, np.full(11, 0.4)]),
            "gap_se": 0.0,
        }
    )
    s = an.curve_summary(lc).set_index("method")
    assert s.loc["legs", "final"] == pytest.approx(0.0)
    assert s.loc["legs", "area"] == pytest.approx(0.25)
    assert s.loc["dexnet", "area"] == pytest.approx(0.4)


def test_prior_kind_comes_from_the_manifest():
    """The report names the prior the problems carried, as the sweep's manifest
    recorded it; results from before the manifests said are 'unknown'."""

    class Res:
        def __init__(self, manifest):
            self._m = manifest

        def manifest(self, experiment):
            return self._m

    assert an.prior_kind(Res({"priors": ["learned"]})) == "learned"
    assert an.prior_kind(Res({"priors": ["learned", "synthetic"]})) == (
        "learned+synthetic"
    )
    assert an.prior_kind(Res({})) == "unknown"
    assert "generated objects" in an.prior_words("learned")
    assert an.prior_words("unknown") == "unknown"
