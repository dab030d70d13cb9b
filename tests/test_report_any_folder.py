"""``python -m legs_jax.figures --results DIR`` on folders a user's sweeps write: a
hyperparameter grid, a subset of objects and methods, some experiments only. Each
gives a report of what is there and exit status 0; the grid's numbers equal
aggregates computed here from runs.parquet."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pandas as pd
import pytest
from results_fixture import DEXNET, EGAD, make_data, write_experiment

from legs_jax import figures as figures_cli
from legs_jax.report import grid

# A product grid over two of LEGS's hyperparameters, as --grid writes it: every
# combination of delta in (0.01, 0.1) and s in (0, 1, 2) in one arm.
DELTAS = (0.01, 0.01, 0.01, 0.1, 0.1, 0.1)
SS = (0.0, 1.0, 2.0, 0.0, 1.0, 2.0)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_data(tmp_path_factory.mktemp("data"))


def _figures(results, out, data, capsys):
    rc = figures_cli.main(
        ["--results", str(results), "--out", str(out), "--data", str(data), "--quiet"]
    )
    return rc, capsys.readouterr().err


def test_a_two_axis_grid_is_reported_against_its_axes(tmp_path, data, capsys):
    results = tmp_path / "my_grid"
    write_experiment(
        results,
        "main",
        [("legs", "", {"delta": DELTAS, "s": SS})],
        DEXNET + EGAD,
        seed=3,
    )
    rc, err = _figures(results, results, data, capsys)
    assert rc == 0, err
    assert "error" not in err
    tables = results / "tables"
    for stem in ("grid_main", "grid_main_per_object"):
        for ext in ("md", "tex", "csv"):
            assert (tables / f"{stem}.{ext}").is_file()
    assert (results / "figures" / "grid_main.png").stat().st_size > 10_000
    # Table I cannot be made of a grid, and is not attempted
    assert not (tables / "table1.md").exists()

    # per set and grid point: mean and SE across objects of per-object means
    runs = pd.read_parquet(results / "main" / "runs.parquet")
    got = pd.read_csv(tables / "grid_main.csv")
    assert len(got) == 2 * 6  # two sets x six grid points
    for set_, objs in (("dexnet_adv", DEXNET), ("egad_eval", EGAD)):
        for d, s in zip(DELTAS, SS, strict=True):
            sel = runs[
                (runs["set"] == set_)
                & np.isclose(runs["delta"], d)
                & np.isclose(runs["s"], s)
            ]
            per_obj = np.array(
                [sel.loc[sel["object"] == o, "final_gap"].mean() for o in objs]
            )
            row = got[
                (got["set"] == set_)
                & np.isclose(got["delta"], d)
                & np.isclose(got["s"], s)
            ]
            assert len(row) == 1
            assert row["n_objects"].item() == len(objs)
            # the CSV carries 6 significant digits
            assert row["mean"].item() == pytest.approx(per_obj.mean(), rel=1e-5)
            se = per_obj.std(ddof=1) / np.sqrt(len(objs))
            assert row["se"].item() == pytest.approx(se, rel=1e-5)

    report = (results / "REPORT.md").read_text()
    assert "## Grid: main over s, delta" in report
    assert "figures/grid_main.png" in report
    # the other experiments were never run: listed as such, not as errors
    for exp in ("case_study", "early_stopping", "prior_strength", "confidence"):
        assert f"| {exp} | not run |" in report
    assert "| main | complete |" in report
    assert "results are missing" not in report


def test_a_one_axis_grid_and_a_subset_of_methods(tmp_path, data, capsys):
    results = tmp_path / "subset"
    # one grid axis for LEGS beside an ordinary arm: the grid's report
    write_experiment(
        results,
        "main",
        [("legs", "", {"delta": (0.01, 0.05, 0.1)}), ("tql", "", {})],
        DEXNET[:2],
        seed=4,
    )
    rc, err = _figures(results, results, data, capsys)
    assert rc == 0, err
    got = pd.read_csv(results / "tables" / "grid_main.csv")
    assert set(got["method"]) == {"legs", "tql"}
    assert sorted(got.loc[got["method"] == "legs", "delta"]) == [0.01, 0.05, 0.1]
    assert "## Grid: main over delta" in (results / "REPORT.md").read_text()


def test_a_subset_without_a_grid_gets_table_one(tmp_path, data, capsys):
    results = tmp_path / "two_methods"
    write_experiment(
        results, "main", [("legs", "", {}), ("tql", "", {})], DEXNET[:2], seed=5
    )
    rc, err = _figures(results, results, data, capsys)
    assert rc == 0, err
    assert (results / "tables" / "table1.md").is_file()
    assert not (results / "tables" / "grid_main.md").exists()
    report = (results / "REPORT.md").read_text()
    assert "## Table I" in report and "| prior_strength | not run |" in report


def test_declared_grids_are_not_user_grids():
    import experiments

    for name in ("prior_strength", "confidence"):
        arms = experiments.get(name).ARMS
        param = {"prior_strength": "s", "confidence": "delta"}[name]
        values = [v for v in arms[0][2].values() if isinstance(v, tuple)][0]
        runs = pd.DataFrame(
            {
                "method": "legs",
                "variant": "",
                param: list(values),
                "final_gap": 0.1,
            }
        )
        assert grid.grid_axes(runs) == [param]
        assert grid.user_grid(runs, arms) == []
        assert grid.user_grid(runs, experiments.get("main").ARMS) == [param]
