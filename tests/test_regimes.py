"""The regimes experiment: discovered, its generated problems planned by the sweep,
and its analysis (tables, maps, report section) run on a small fixture whose
answer is known: LEGS is below BORGES (K=100) and BORGES (K=2000) on one problem
only, above them elsewhere."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pandas as pd
import pytest

import experiments
from legs_jax import families, synthetic
from legs_jax.core import methods, problem
from legs_jax.report.figures import Run
from legs_jax.sweep import cli
from legs_jax.sweep import experiments as planning
from legs_jax.sweep.config import SweepConfig, validate
from legs_jax.sweep.plan import SweepError

DECL = experiments.get("regimes")


def test_discovered_with_every_method_and_generated_problems():
    assert "regimes" in experiments.EXPERIMENTS
    names = [n for n, _ in DECL.GENERATED]
    assert len(set(names)) == len(names) and tuple(names) == DECL.OBJECTS
    assert set(methods.names()) <= {m for m, _, _ in DECL.ARMS}
    for _, kw in DECL.GENERATED:  # every family is a valid set of arguments
        families.rho_for_auc(kw["auc"])
        families.landing(kw["num_poses"], kw["effective_poses"])


def _plan(tmp_path, *extra):
    parser = cli.build_parser()
    a = validate(
        SweepConfig.from_namespace(
            parser.parse_args(["--experiment", "regimes", *extra])
        )
    )
    return planning._experiment_plan("regimes", a, None, tmp_path)


def test_the_sweep_plans_the_generated_problems(tmp_path):
    pick = ["hump-auc0.50", "bimodal-auc0.95"]
    plan = _plan(tmp_path, "--smoke", "--objects", *pick, "--methods", "legs")
    assert [o.name for o in plan.objects] == pick
    for o in plan.objects:  # smoke size, generated once, deterministic
        pb = problem.load(o.path)
        assert (pb.num_poses, pb.num_grasps, pb.num_trials) == (4, 200, 1)
        kw = dict(DECL.GENERATED)[o.name]
        assert pb.meta["family"]["shape"] == kw["shape"]
    again = _plan(tmp_path, "--smoke", "--objects", *pick, "--methods", "legs")
    assert [o.sha256 for o in again.objects] == [o.sha256 for o in plan.objects]
    # LEGS's own arms: the default and the settings the issue points at.
    assert {a.label for a in plan.arms} == {
        "legs",
        "legs.gamma",
        "legs.k20",
        "legs.n20",
    }
    with pytest.raises(SweepError, match="unknown generated problem 'hump-auc0.5'"):
        _plan(tmp_path, "--smoke", "--objects", "hump-auc0.5")


# ----------------------------------------------------------------- the analysis
OBJ = ["hump-auc0.50", "hump-auc0.95", "bimodal-auc0.50", "bimodal-auc0.95"]
SIDE = "hump-auc0.85-pessimistic"
WIN = "bimodal-auc0.95"  # the one problem where LEGS is below both BORGES
REAL = ["bar_clamp", "gearbox"]


def _runs(objects, arms, gap, experiment, set_):
    rng = np.random.default_rng(0)
    rows = []
    for o in objects:
        for method, variant, gamma in arms:
            for t in range(2):
                for r in range(10):
                    rows.append(
                        dict(
                            experiment=experiment,
                            set=set_,
                            object=o,
                            method=method,
                            variant=variant,
                            trial=t,
                            rollout=r,
                            s=1.0,
                            prior_offset=1.0,
                            delta=0.05,
                            gamma=gamma,
                            k=100,
                            n=100,
                            horizon=3000,
                            final_gap=gap(o, method, variant, gamma)
                            + 0.005 * rng.normal(),
                        )
                    )
    return pd.DataFrame(rows)


def _gap(o, method, variant, gamma):
    base = {"borges_100": 0.10, "borges_2000": 0.12, "bayes_ucb_100": 0.09}
    if method == "legs":
        g = 0.05 if o in (WIN, "bar_clamp") else 0.15
        return g - 0.02 if variant == "gamma" and gamma == 0.8 else g
    return base[method]


ARMS = [
    ("legs", "", 0.2),
    ("legs", "gamma", 0.5),
    ("legs", "gamma", 0.8),
    ("borges_100", "", 0.2),
    ("borges_2000", "", 0.2),
    ("bayes_ucb_100", "", 0.2),
]


@pytest.fixture
def fixture_run(tmp_path) -> Run:
    root = tmp_path / "results"
    (root / "regimes").mkdir(parents=True)
    (root / "main").mkdir()
    objs = [*OBJ, SIDE]
    _runs(objs, ARMS, _gap, "regimes", "generated").to_parquet(
        root / "regimes" / "runs.parquet"
    )
    files = []
    for o in objs:  # small files of the declared families, as the sweep writes them
        kw = {**dict(DECL.GENERATED)[o], "num_grasps": 200, "num_trials": 1}
        path = tmp_path / "gen" / f"{o}.npz"
        problem.save(families.make_problem(name=o, **kw), path)
        files.append(str(path))
    pd.DataFrame({"object": objs, "problem_file": files}).to_parquet(
        root / "regimes" / "objects.parquet"
    )
    main_arms = [a for a in ARMS if a[1] == ""]
    _runs(REAL, main_arms, _gap, "main", "dexnet_adv").to_parquet(
        root / "main" / "runs.parquet"
    )
    data = tmp_path / "data"
    for i, o in enumerate(REAL):
        pb = synthetic.make_problem(
            i, num_poses=3, num_grasps=150, num_trials=2, name=o
        )
        problem.save(pb, data / "problems" / "dexnet_adv" / f"{o}.npz")
    return Run.start(root, tmp_path / "out", data)


def test_analysis_on_a_fixture_with_a_known_answer(fixture_run):
    mod = experiments.analysis("regimes")
    mod._step(fixture_run)
    names = {p.name for p in fixture_run.written}
    assert {
        "regimes.md",
        "regimes.csv",
        "regimes_real.csv",
        "regimes_map.png",
        "regimes_side.png",
    } <= names
    t = pd.read_csv(fixture_run.tables / "regimes.csv").set_index("object")
    assert t.loc[WIN, "diff_borges_100"] == pytest.approx(-0.05, abs=0.01)
    assert t.loc["hump-auc0.50", "diff_borges_2000"] == pytest.approx(0.03, abs=0.01)
    # The measured features of the small files: the C-index near the declared one.
    assert t.loc["hump-auc0.95", "auc"] == pytest.approx(0.95, abs=0.03)
    assert t.loc["hump-auc0.50", "auc"] == pytest.approx(0.5, abs=0.05)
    real = pd.read_csv(fixture_run.tables / "regimes_real.csv").set_index("object")
    assert real.loc["bar_clamp", "diff_borges_100"] == pytest.approx(-0.05, abs=0.01)
    assert real.loc["gearbox", "diff_borges_100"] == pytest.approx(0.05, abs=0.01)

    text = "\n".join(mod._section(fixture_run.ctx))
    assert "appears on 1 problem(s): `bimodal-auc0.95`." in text
    assert "LEGS − BORGES (K=100): from -0.050 (`bimodal-auc0.95`)" in text
    assert "higher on 4" in text
    assert "The 2 real objects" in text and "1 of 2 objects below 0" in text
    # LEGS with γ = 0.8 is below the default on every problem.
    assert "| legs.gamma gamma=0.8 |" in text and "| 5 / 0 |" in text


def test_report_says_when_no_problem_shows_the_papers_ordering(fixture_run):
    runs = fixture_run.res.table("regimes", "runs")
    runs.loc[(runs["object"] == WIN) & (runs["method"] == "legs"), "final_gap"] += 0.1
    mod = experiments.analysis("regimes")
    mod._step(fixture_run)
    text = "\n".join(mod._section(fixture_run.ctx))
    assert "appears on none of the explored problems" in text


def test_section_without_results():
    mod = experiments.analysis("regimes")
    assert "_Not available" in "\n".join(mod._section({}))


def test_smoke_problem_folder_is_inside_the_output(tmp_path):
    plan = _plan(tmp_path, "--smoke", "--methods", "dexnet")
    assert len(plan.objects) == 2
    for o in plan.objects:
        assert Path(o.path).is_relative_to(tmp_path)


def test_our_method_against_the_lowest_other_arm(fixture_run):
    """With our method's runs added (0.02 everywhere but 0.20 on one problem, where
    Bayes-UCB (K=100) at 0.09 is the lowest other arm), the section names that one
    problem and its lowest arm, and the figure of every problem is written."""
    ours = DECL.OURS

    def gap(o, method, variant, gamma):
        return 0.20 if o == "hump-auc0.50" else 0.02

    root = fixture_run.res.root
    runs = pd.read_parquet(root / "regimes" / "runs.parquet")
    extra = _runs([*OBJ, SIDE], [(ours, "", 0.2)], gap, "regimes", "generated")
    pd.concat([runs, extra], ignore_index=True).to_parquet(
        root / "regimes" / "runs.parquet"
    )
    fixture_run = Run.start(root, root.parent / "out2", root.parent / "data")
    mod = experiments.analysis("regimes")
    mod._step(fixture_run)
    vb = mod.versus_best(fixture_run.ctx["regimes"]["table"])
    assert vb.loc["hump-auc0.50", "best"] == "bayes_ucb_100"
    assert vb.loc["hump-auc0.50", "diff"] == pytest.approx(0.11, abs=0.01)
    assert (vb.drop("hump-auc0.50")["diff"] < 0).all()
    assert "regimes_ours.png" in {p.name for p in fixture_run.written}
    text = "\n".join(mod._section(fixture_run.ctx))
    label = methods.get(ours).card.label
    assert (
        f"- {label}: above the lowest other arm by more than 2 SE on 1 of 5 "
        f"problems (`hump-auc0.50`; the lowest there: "
        f"{methods.get('bayes_ucb_100').card.short_label})"
    ) in text
    assert "(figures/regimes_ours.png)" in text
