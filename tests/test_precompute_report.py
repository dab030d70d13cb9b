"""``python -m precompute report``: per-object statistics equal a plain computation,
per-set gaps sit beside the paper's, figures are drawn, bad input is refused."""

from __future__ import annotations

import csv
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest

from legs_jax import synthetic
from legs_jax.core import problem
from precompute import report
from precompute.cli import main as cli_main


def _plain_gaps(pb):
    """Dex-Net and K100-UB gaps by loops, mean over trials."""
    T, P, _ = pb.robustness.shape
    dex, ub = np.zeros(T), np.zeros(T)
    for t in range(T):
        for s in range(P):
            ok = np.flatnonzero(pb.valid[t, s])
            if len(ok) == 0:
                continue
            p, q = pb.robustness[t, s, ok], pb.prior[t, s, ok]
            best = p.max()
            greedy = ok[np.argmax(q)]  # first maximum = lowest id
            top = ok[np.argsort(-q, kind="stable")[:100]]
            dex[t] += pb.landing[s] * (best - pb.robustness[t, s, greedy])
            ub[t] += pb.landing[s] * (best - pb.robustness[t, s, top].max())
    return dex.mean(), ub.mean()


def test_object_row_matches_plain_computation():
    pb = synthetic.make_problem(
        seed=3, num_poses=5, num_grasps=300, num_trials=3, invalid_fraction=0.1
    )
    row = report.object_row(pb, "dexnet_adv")
    dex, ub = _plain_gaps(pb)
    assert row["dexnet_gap"] == pytest.approx(dex, abs=1e-6)
    assert row["k100_ub_gap"] == pytest.approx(ub, abs=1e-6)
    assert row["poses"] == 5
    assert row["valid_grasps"] == int(pb.valid.sum())
    p = pb.robustness[pb.valid]
    assert row["frac_p_ge_0.5"] == pytest.approx((p >= 0.5).mean())
    corr = np.corrcoef(p, pb.prior[pb.valid])[0, 1]
    assert row["prior_truth_corr"] == pytest.approx(corr, abs=1e-9)
    assert len(row["landing"].split(";")) == 5


def test_set_rows_compare_with_the_paper():
    rows = [
        {
            "set": "dexnet_adv",
            "dexnet_gap": g,
            "k100_ub_gap": u,
            "prior_truth_corr": 0.3,
            "frac_p_ge_0.5": 0.1,
        }
        for g, u in ((0.50, 0.10), (0.60, 0.06), (0.58, 0.26))
    ]
    (s,) = report.set_rows(rows)
    assert s["objects"] == 3
    assert s["dexnet_gap"] == pytest.approx(0.56)
    assert s["dexnet_gap_se"] == pytest.approx(
        np.std([0.5, 0.6, 0.58], ddof=1) / 3**0.5
    )
    assert s["dexnet_gap_within_0.05"]
    assert s["k100_ub_gap"] == pytest.approx(0.14)
    assert not s["k100_ub_gap_within_0.05"]  # 0.14 vs the paper's 0.08


def test_cli_writes_tables_and_figures(tmp_path, capsys):
    probs = tmp_path / "problems"
    pb = synthetic.make_problem(seed=1, num_poses=3, num_grasps=200, name="bar_clamp")
    problem.save(pb, probs / "dexnet_adv" / "bar_clamp.npz")
    out = tmp_path / "out"
    code = cli_main(["report", "--problems", str(probs), "--out", str(out), "--quiet"])
    assert code == 0
    with open(out / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["object"] for r in rows] == ["bar_clamp"]
    assert float(rows[0]["dexnet_gap"]) == pytest.approx(_plain_gaps(pb)[0], abs=1e-5)
    assert "synthetic" in (out / "sets.md").read_text()
    for f in (
        out / "figures" / "poses" / "dexnet_adv" / "bar_clamp.png",
        out / "figures" / "robustness_dexnet_adv.png",
    ):
        assert f.stat().st_size > 5000


def test_cli_without_problems_is_a_clear_error(tmp_path, capsys):
    code = cli_main(["report", "--problems", str(tmp_path), "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert "no problem files under" in err and "precompute --all" in err
