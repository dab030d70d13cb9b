"""Sweep bookkeeping: experiment specs, chunk plans, tables, merging, resuming.

These tests replace the rollout engine by ``sweep_fakes.fake_run`` (results of the
engine's shapes that depend only on seed, object, trial, rollout and
hyperparameters), so they check the sweep machinery alone, in milliseconds. The
real engine runs in ``test_sweep.py``.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import stat
import types
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import sweep_fakes

import experiments

# ---------------------------------------------------------------------- helpers
from legs_jax import results, sweep, synthetic
from legs_jax.core import methods, problem
from legs_jax.errors import ConfigError


@pytest.fixture(autouse=True)
def _keep_xla_flags(monkeypatch):
    """main() asks for host devices through XLA_FLAGS: keep that in this test."""
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))


@pytest.fixture
def fake_engine(monkeypatch):
    calls = []
    eng = types.SimpleNamespace(
        run=functools.partial(sweep_fakes.fake_run, calls=calls),
        compile_seconds=lambda: 0.0,
    )
    monkeypatch.setattr(sweep.execute, "_engine", lambda: eng)
    return calls


def _problems(folder: Path, specs) -> list[str]:
    paths = []
    for name, poses, grasps in specs:
        pb = synthetic.make_problem(
            seed=len(paths), num_poses=poses, num_grasps=grasps, num_trials=3, name=name
        )
        paths.append(str(problem.save(pb, folder / f"{name}.npz")))
    return paths


def _plan(objects, arms, trials=3, rollouts=2, horizon=300, check_methods=("legs",)):
    plan = sweep.ExperimentPlan(
        name="main",
        description="test",
        objects=objects,
        arms=[sweep.make_arm(*a) for a in arms],
        trials=trials,
        rollouts=rollouts,
        horizon=horizon,
        record_every=10,
        check_every=100,
        check_methods=check_methods,
        active_set_methods=(),
        seed=0,
        smoke=False,
    )
    return plan


def _obj(name, P, K, T=10, oid=None):
    return sweep.ObjectEntry(
        name=name,
        set="s",
        object_id=oid if oid is not None else len(name),
        path=f"{name}.npz",
        sha256="0" * 64,
        num_poses=P,
        num_grasps=K,
        num_trials=T,
    )


def _read_all(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*.parquet"))
        if "chunks" not in p.parts
    }


# ------------------------------------------------------------------ experiments
@pytest.mark.parametrize("name", experiments.EXPERIMENTS)
def test_experiment_modules_declare_valid_arms(name):
    mod = experiments.get(name)
    assert mod.NAME == name
    arms = [sweep.make_arm(*a) for a in mod.ARMS]
    assert arms
    assert set(mod.CHECK_METHODS) <= {a.method for a in arms}
    if not getattr(mod, "GENERATED", ()):  # the paper's sizes
        assert mod.TRIALS == 10 and mod.ROLLOUTS == 10 and mod.HORIZON == 3000
    assert 1 <= len(mod.SMOKE_OBJECTS) <= 2


def test_paper_grids_and_extra_row():
    main = [sweep.make_arm(*a) for a in experiments.get("main").ARMS]
    paper = set(experiments.get("main").TABLE_ORDER)
    # Table I's rows beyond the paper's: Bayes-UCB and our own method
    extra = {"bayes_ucb_100", "bayes_ucb_2000", "pooled_ucb"}
    assert {a.method for a in main} == paper | extra
    assert paper | extra <= set(methods.names())
    synthetic = [sweep.make_arm(*a) for a in experiments.get("prior_synthetic").ARMS]
    assert [a.label for a in synthetic] == [
        a.method for a in main if a.method in paper and not a.variant
    ]
    assert experiments.get("prior_synthetic").PRIOR == "synthetic"
    orig = [a for a in main if a.variant == "orig_prior"]
    assert len(orig) == 1 and orig[0].method == "borges_2000"
    assert dict(orig[0].grid[0])["prior_offset"] == 0.0
    assert dict(orig[0].grid[0])["s"] == 5.0
    (ps,) = [sweep.make_arm(*a) for a in experiments.get("prior_strength").ARMS]
    assert [dict(g)["s"] for g in ps.grid] == [0, 1, 2, 3, 4, 5]
    assert {dict(g)["delta"] for g in ps.grid} == {0.07}
    (cf,) = [sweep.make_arm(*a) for a in experiments.get("confidence").ARMS]
    assert [dict(g)["delta"] for g in cf.grid] == [0.01, 0.05, 0.10, 0.15, 0.20, 0.25]
    assert {dict(g)["s"] for g in cf.grid} == {1.0}
    assert experiments.get("case_study").OBJECTS == (
        "climbing_hold",
        "C3",
        "F6",
        "turbine_housing",
    )


def test_arms_hold_every_result_column():
    """A method's own hyperparameters with their values, the other columns with
    the defaults of the methods declaring them."""
    cols = methods.column_defaults()
    for name in methods.names():
        (point,) = sweep.make_arm(name, "", {}).grid
        assert dict(point) == {**cols, **methods.get(name).defaults()}
    (point,) = sweep.make_arm("tql", "", {"epsilon": 0.3}).grid
    assert dict(point)["epsilon"] == 0.3 and dict(point)["k"] == 100
    with pytest.raises(sweep.SweepError, match="unknown hyperparameter.*of tql"):
        sweep.make_arm("tql", "", {"delta": 0.1})


@pytest.mark.parametrize(
    "hp, match",
    [
        ({"delta": 0.0}, "delta"),
        ({"delta": 1.0}, "delta"),
        ({"gamma": 1.5}, "gamma"),
        ({"s": -1.0}, "s must be"),
        ({"epsilon": 1.1}, "epsilon"),
        ({"k": 0}, "k must be"),
        ({"k": (50, 100)}, "static"),
        ({"s": (1.0, 2.0), "delta": (0.1,)}, "equal lengths"),
        ({"bogus": 1}, "unknown hyperparameter"),
    ],
)
def test_make_arm_refuses_bad_hyperparameters(hp, match):
    with pytest.raises(sweep.SweepError, match=match):
        sweep.make_arm("legs", "", hp)


def test_make_arm_zips_grids():
    arm = sweep.make_arm("legs", "", {"s": (0.0, 2.0), "delta": (0.1, 0.2), "k": 50})
    pts = arm.grid_dicts()
    assert [(p["s"], p["delta"], p["k"], p["gamma"]) for p in pts] == [
        (0.0, 0.1, 50, 0.2),
        (2.0, 0.2, 50, 0.2),
    ]


# -------------------------------------------------------------------- chunking
def test_plan_covers_every_run_once_and_is_deterministic():
    objects = [
        _obj("a", 3, 2000),
        _obj("b", 5, 2000),
        _obj("c", 4, 2000),
        _obj("d", 12, 2000),
        *(_obj(n, 4, 2000) for n in "efgh"),
    ]
    arms = [("dexnet", "", {}), ("borges_2000", "", {}), ("legs", "", {})]
    plan = _plan(objects, arms, trials=10, rollouts=10, horizon=3000)
    chunks = sweep.plan_chunks(plan)
    again = sweep.plan_chunks(
        _plan(objects, arms, trials=10, rollouts=10, horizon=3000)
    )
    assert [(c.id, c.hash) for c in chunks] == [(c.id, c.hash) for c in again]
    assert len({c.id for c in chunks}) == len(chunks)
    seen = set()
    for c in chunks:
        for o in c.objects:
            # An object shares a chunk only with objects of its padded shape.
            assert c.num_poses == sweep.plan._pose_bucket(objects[o].num_poses)
            for t in c.trials:
                key = (c.arm, o, t)
                assert key not in seen
                seen.add(key)
    assert seen == {(a, o, t) for a in range(3) for o in range(8) for t in range(10)}
    # Work per chunk respects the budget unless a single trial is already bigger.
    for c in chunks:
        assert c.work <= sweep.WORK_BUDGET or len(c.trials) == 1
    # K=2000 methods get smaller chunks than the constant rows.
    n_by_arm = {a: sum(1 for c in chunks if c.arm == a) for a in range(3)}
    assert n_by_arm[1] > n_by_arm[0]


def test_plan_splits_trials_when_one_object_is_too_big():
    plan = _plan([_obj("a", 4, 2000)], [("borges_2000", "", {})], trials=10)
    arm = sweep.make_arm("borges_2000", "", {})
    per_trial = 2 * sweep.plan._rollout_work(arm, 4, 2000, 300, 0)
    chunks = sweep.plan_chunks(plan, work_budget=3.5 * per_trial)
    sizes = [len(c.trials) for c in chunks]
    assert len(chunks) > 1 and sum(sizes) == 10 and max(sizes) - min(sizes) <= 1
    assert sizes == [3, 3, 2, 2]
    assert [c.trials[0] for c in chunks] == [0, 3, 6, 8]


def test_chunk_hash_depends_on_results_inputs_only():
    a = sweep.plan_chunks(_plan([_obj("a", 4, 200)], [("legs", "", {})]))
    b = sweep.plan_chunks(_plan([_obj("a", 4, 200)], [("legs", "", {})], horizon=200))
    c = sweep.plan_chunks(_plan([_obj("a", 4, 200)], [("legs", "", {"s": 2.0})]))
    assert a[0].id == b[0].id == c[0].id
    assert len({a[0].hash, b[0].hash, c[0].hash}) == 3


# --------------------------------------------------------------------- tables
def _ctx(grid_points=1, trials=(0, 1), rollouts=2, **kw):
    grid = [dict(methods.column_defaults(), s=float(g)) for g in range(grid_points)]
    return results.ChunkContext(
        experiment="main",
        method="legs",
        variant="",
        grid=grid,
        objects=[("x", "dexnet_adv"), ("y", "egad_eval")],
        trials=trials,
        rollouts=range(rollouts),
        seed=3,
        horizon=300,
        record_checks=True,
        **kw,
    )


def _fake_batch(O=2, T=2, P=3, K=20):  # noqa: E741
    return types.SimpleNamespace(
        robustness=np.random.default_rng(0).random((O, T, P, K)).astype(np.float32),
        pose_valid=np.ones((O, P), bool),
    )


def test_chunk_tables_rows_match_arrays():
    batch = _fake_batch()
    out = sweep_fakes.fake_run(
        batch,
        "legs",
        object_ids=[7, 8],
        trials=[0, 1],
        num_rollouts=2,
        horizon=300,
        hparams={"s": (0.0, 1.0)},
        record_active_set=True,
    )
    ctx = _ctx(2, record_active_set=True, robustness=batch.robustness)
    t = results.chunk_tables(out, ctx)
    runs, checks, act = t["runs"], t["checks"], t["active_set"]
    assert len(runs) == 2 * 2 * 2 * 2
    row = runs[(runs.object == "y") & (runs.trial == 1) & (runs.rollout == 0)]
    row = row[row.s == 1.0].iloc[0]
    assert row.final_gap == pytest.approx(float(out.final_gap[1, 1, 1, 0]))
    assert row.successes == out.successes[1, 1, 1, 0]
    assert row["set"] == "egad_eval" and row.seed == 3 and row.horizon == 300
    np.testing.assert_array_equal(row.gap_curve, out.gap_curve[1, 1, 1, 0])
    assert len(checks) == 16 * 3 and set(checks.step) == {100, 200, 300}
    c = checks[(checks.object == "x") & (checks.trial == 0) & (checks.rollout == 1)]
    c = c[(c.s == 0.0) & (c.step == 200)].iloc[0]
    assert c.p_lower == pytest.approx(float(out.check_p_lower[0, 0, 0, 1, 1]))
    assert c.p_lower_attempted == pytest.approx(
        float(out.check_p_lower_attempted[0, 0, 0, 1, 1])
    )
    # Active set: trial 0, rollout 0 only, filled slots only, with their p.
    assert set(act.trial) == {0} and set(act.rollout) == {0}
    a = out.active_set[0, 1, 0, 0]
    assert (act.grid_index == 0).sum() // 1 >= 1
    sub = act[(act.object == "y") & (act.grid_index == 0)]
    assert len(sub) == int((a >= 0).sum())
    r = sub.iloc[0]
    step_i = [100, 200, 300].index(r.step)
    assert a[step_i, r.pose, r.slot] == r.grasp
    assert r.robustness == pytest.approx(batch.robustness[1, 0, r.pose, r.grasp])


def test_merge_aggregates_curves_and_ignores_chunking(tmp_path):
    batch = _fake_batch(O=2, T=4)
    kw = dict(object_ids=[7, 8], num_rollouts=3, horizon=300, hparams={"s": 1.0})
    whole = sweep_fakes.fake_run(batch, "legs", trials=[0, 1, 2, 3], **kw)
    arms, objs = [("legs", "")], ["x", "y"]

    def write(folder, splits):
        ids = []
        for i, trials in enumerate(splits):
            out = sweep_fakes.fake_run(batch, "legs", trials=list(trials), **kw)
            ctx = _ctx(trials=trials, rollouts=3)
            tables = results.chunk_tables(out, ctx)
            meta = {"curve_steps": out.curve_steps.tolist()}
            results.write_chunk(folder, f"c{i}", tables, meta)
            ids.append(f"c{i}")
        return results.merge_chunks(folder, ids[::-1], arms, objs)

    one = write(tmp_path / "a", [(0, 1, 2, 3)])
    two = write(tmp_path / "b", [(2, 3), (0, 1)])
    for name in ("runs", "curves", "checks"):
        pd.testing.assert_frame_equal(one[name], two[name])
    runs, curves = one["runs"], one["curves"]
    assert list(runs.columns[:5]) == [
        "experiment",
        "set",
        "object",
        "method",
        "variant",
    ]
    assert list(runs.trial[:3]) == [0, 0, 0] and list(runs.rollout[:3]) == [0, 1, 2]
    # Mean and standard error of object y over its 4 x 3 runs, from the arrays.
    y = whole.gap_curve[0, 1].reshape(12, -1).astype(np.float64)
    cy = curves[curves.object == "y"]
    assert list(cy.step) == list(range(0, 301, 10))
    np.testing.assert_allclose(cy.gap_mean, y.mean(0), rtol=1e-12)
    np.testing.assert_allclose(cy.gap_se, y.std(0, ddof=1) / np.sqrt(12), rtol=1e-12)
    assert set(cy.n_runs) == {12}


def test_write_chunk_is_atomic(tmp_path, monkeypatch):
    df = pd.DataFrame({"a": [1, 2]})
    calls = {"n": 0}
    real = results.atomic_write_json

    def boom(obj, path):
        calls["n"] += 1
        raise KeyboardInterrupt

    monkeypatch.setattr(results, "atomic_write_json", boom)
    with pytest.raises(KeyboardInterrupt):
        results.write_chunk(tmp_path, "c0", {"runs": df}, {"x": 1})
    assert calls["n"] == 1
    assert list(tmp_path.iterdir()) == []  # nothing half-written is left
    monkeypatch.setattr(results, "atomic_write_json", real)
    assert results.write_chunk(tmp_path, "c0", {"runs": df}, {"x": 1})
    assert results.chunk_done(tmp_path, "c0")
    assert not results.write_chunk(tmp_path, "c0", {"runs": df}, {"x": 1})


# ------------------------------------------------------------------- CLI, fake
def _cli(args, capsys):
    code = sweep.main([*args, "--quiet", "--compile-cache", "off"])
    return code, capsys.readouterr().err


@pytest.fixture
def probs(tmp_path):
    return _problems(tmp_path, [("alpha", 3, 200), ("beta", 5, 200)])


def test_cli_runs_and_writes_schema(tmp_path, probs, fake_engine, capsys, monkeypatch):
    monkeypatch.delenv("LEGS_JAX_CPU_VECTOR_WIDTH", raising=False)
    out = tmp_path / "out"
    args = ["--experiment", "main", "--problems", *probs, "--out", str(out)]
    code, err = _cli(
        [*args, "--trials", "2", "--rollouts", "2", "--horizon", "200"], capsys
    )
    assert code == 0, err
    d = out / "main"
    runs = pd.read_parquet(d / "runs.parquet")
    need = ["experiment", "set", "object", "method", "variant", "trial", "rollout"]
    need += ["seed", *results.hparam_columns(), "horizon", "final_gap"]
    need += ["final_performance", "successes", "distinct_grasps", "replacements"]
    assert list(runs.columns) == need
    n_arms = len(experiments.get("main").ARMS)
    assert len(runs) == n_arms * 2 * 2 * 2  # arms x objects x trials x rollouts
    orig = runs[runs.variant == "orig_prior"]
    assert set(orig.method) == {"borges_2000"} and set(orig.prior_offset) == {0.0}
    curves = pd.read_parquet(d / "curves.parquet")
    assert set(curves.n_runs) == {4} and len(curves) == n_arms * 2 * 21
    checks = pd.read_parquet(d / "checks.parquet")
    assert set(checks.method) == {"legs"} and len(checks) == 2 * 2 * 2 * 2
    man = json.loads((d / "manifest.json").read_text())
    assert man["status"] == "complete"
    assert man["chunks_done"] == man["chunks_total"] == len(man["chunks"])
    assert all(c["wall_s"] >= 0 for c in man["chunks"].values())
    # compile time apart from run time, per chunk and in all
    assert all(c["compile_s"] >= 0 and c["run_s"] >= 0 for c in man["chunks"].values())
    assert man["compile_s_chunks"] >= 0
    sha = results.sha256_file(probs[0])
    assert man["problem_files"]["alpha"]["sha256"] == sha
    # synthetic.make_problem's q is made from p: the synthetic kind
    assert man["problem_files"]["alpha"]["prior"] == man["priors"][0] == "synthetic"
    assert man["versions"]["jax"] and man["sessions"][0]["devices"]["count"] >= 1
    # the XLA options of the simulation programs, which can move a bound's bits
    wide = {"xla_cpu_prefer_vector_width": 512}
    isa_wide = man["versions"]["isa"] == "AVX-512"
    assert man["sessions"][0]["devices"]["xla_options"] == (wide if isa_wide else {})
    assert "commit" in man["git"]


def test_merged_results_without_chunks_are_kept(tmp_path, probs, fake_engine, capsys):
    """A fresh clone of committed results (merged tables, no chunk folders) is not
    recomputed; --overwrite recomputes it; other configurations still refuse."""
    out = tmp_path / "out"
    args = ["--experiment", "confidence", "--problems", *probs, "--out", str(out)]
    args += ["--trials", "1", "--rollouts", "2", "--horizon", "100"]
    code, err = _cli(args, capsys)
    assert code == 0, err
    d = out / "confidence"
    before = (d / "runs.parquet").read_bytes()
    shutil.rmtree(d / "chunks")
    calls = len(fake_engine)
    code = sweep.main([*args, "--compile-cache", "off"])  # not quiet: the message
    err = capsys.readouterr().err
    assert code == 0, err
    assert len(fake_engine) == calls  # nothing ran
    assert "confidence: complete results already in" in err
    assert (d / "runs.parquet").read_bytes() == before
    code, err = _cli([*args, "--overwrite"], capsys)
    assert code == 0, err
    assert len(fake_engine) > calls
    assert (d / "runs.parquet").read_bytes() == before
    shutil.rmtree(d / "chunks")
    code, err = _cli([*args[:-2], "--horizon", "200"], capsys)
    assert code == 2 and "different configuration" in err


def _files(folder: Path) -> dict[str, tuple[bytes, int]]:
    return {
        p.relative_to(folder).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_complete_experiment_is_left_untouched(tmp_path, probs, fake_engine, capsys):
    out = tmp_path / "out"
    args = ["--experiment", "confidence", "--problems", *probs, "--out", str(out)]
    args += ["--trials", "1", "--rollouts", "2", "--horizon", "100"]
    assert _cli(args, capsys)[0] == 0
    before, calls = _files(out), len(fake_engine)
    code = sweep.main([*args, "--compile-cache", "off"])  # not quiet: the message
    err = capsys.readouterr().err
    assert code == 0, err
    assert "confidence: complete in" in err and "every file left as it is" in err
    assert len(fake_engine) == calls and _files(out) == before


@pytest.mark.parametrize("damage", ["truncate", "flip", "delete", "meta"])
def test_damaged_chunk_is_recomputed(tmp_path, probs, fake_engine, capsys, damage):
    """A finished chunk whose file was cut short, altered or lost (or whose
    chunk.json is garbage) is found by its SHA-256, named in a warning and
    computed again; the merged tables equal an undamaged run's."""
    base = ["--experiment", "main", "--problems", *probs, "--trials", "2"]
    base += ["--rollouts", "2", "--horizon", "100", "--methods", "legs,tql"]
    assert _cli([*base, "--out", str(tmp_path / "ref")], capsys)[0] == 0
    out = tmp_path / "out"
    assert _cli([*base, "--out", str(out)], capsys)[0] == 0
    chunk = sorted((out / "main" / "chunks").iterdir())[0]
    f = chunk / "runs.parquet"
    if damage == "truncate":
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    elif damage == "flip":
        data = bytearray(f.read_bytes())
        data[len(data) // 2] ^= 0xFF
        f.write_bytes(bytes(data))
    elif damage == "delete":
        f.unlink()
    else:
        (chunk / results.CHUNK_META).write_text("{not json")
    calls = len(fake_engine)
    code = sweep.main([*base, "--out", str(out), "--compile-cache", "off"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"chunk {chunk.name} is damaged" in err and "recomputing it" in err
    assert "Traceback" not in err
    assert len(fake_engine) == calls + 1  # that chunk alone
    assert _read_all(out) == _read_all(tmp_path / "ref")
    assert results.verify_chunk(chunk.parent, chunk.name) is None


def test_cli_resume_after_interrupt_equals_uninterrupted(
    tmp_path, probs, fake_engine, capsys, monkeypatch
):
    base = ["--experiment", "main", "--problems", *probs, "--trials", "2"]
    base += ["--rollouts", "2", "--horizon", "200"]
    code, err = _cli([*base, "--out", str(tmp_path / "ref")], capsys)
    assert code == 0, err

    real = sweep.execute._run_chunk
    n = {"chunks": 0}

    def interrupt_third(*a, **k):
        n["chunks"] += 1
        if n["chunks"] == 3:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(sweep.execute, "_run_chunk", interrupt_third)
    code, err = _cli([*base, "--out", str(tmp_path / "res")], capsys)
    assert code == 130
    assert "kept 2 of" in err and "resume" in err
    man = json.loads((tmp_path / "res/main/manifest.json").read_text())
    assert man["status"] == "interrupted" and man["chunks_done"] == 2
    assert not (tmp_path / "res/main/runs.parquet").exists()
    monkeypatch.setattr(sweep.execute, "_run_chunk", real)
    fake_engine.clear()
    code, err = _cli([*base, "--out", str(tmp_path / "res")], capsys)
    assert code == 0, err
    assert len(fake_engine) == man["chunks_total"] - 2  # finished chunks skipped
    assert _read_all(tmp_path / "res") == _read_all(tmp_path / "ref")


def test_cli_refuses_other_config_without_overwrite(
    tmp_path, probs, fake_engine, capsys
):
    base = [
        "--experiment",
        "confidence",
        "--problems",
        probs[0],
        "--out",
        str(tmp_path),
    ]
    base += ["--trials", "1", "--rollouts", "1"]
    assert _cli([*base, "--horizon", "100"], capsys)[0] == 0
    before = _read_all(tmp_path)
    code, err = _cli([*base, "--horizon", "200"], capsys)
    assert code == 2
    assert (
        "different configuration" in err and "horizon" in err and "--overwrite" in err
    )
    assert len(err.strip().splitlines()) == 1
    assert _read_all(tmp_path) == before
    code, err = _cli([*base, "--horizon", "200", "--overwrite"], capsys)
    assert code == 0, err
    curves = pd.read_parquet(tmp_path / "confidence/curves.parquet")
    assert curves.step.max() == 200
    assert sorted(set(curves.delta)) == [0.01, 0.05, 0.10, 0.15, 0.20, 0.25]


@pytest.mark.parametrize(
    "args, match",
    [
        (["--experiment", "mian"], "unknown experiment 'mian'.*did you mean main"),
        (["--experiment", "main", "--methods", "leg"], "unknown method 'leg'"),
        (["--experiment", "main", "--trials", "0"], "must be >= 1"),
        (["--experiment", "main", "--horizon", "x"], "expected an integer"),
        (["--experiment", "main", "--problems", "nope.npz"], "no such file"),
        ([], "nothing to run"),
        (["--all", "--experiment", "main"], "not both"),
        (["--all", "--coordinator", "h:1"], "go together"),
    ],
)
def test_cli_refuses_bad_arguments(args, match, capsys):
    with pytest.raises(SystemExit) as e:
        sweep.main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert pytest.importorskip("re").search(match, err), err


def test_cli_refuses_bad_problem_and_too_many_trials(
    tmp_path, probs, fake_engine, capsys
):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    code, err = _cli(["--experiment", "main", "--problems", str(bad)], capsys)
    assert code == 2 and "bad.npz" in err and len(err.strip().splitlines()) == 1
    code, err = _cli(["--experiment", "main", "--problems", probs[0]], capsys)
    assert code == 2 and "has 3 trials" in err
    code, err = _cli(
        ["--experiment", "main", "--problems", probs[0], "--devices", "999"], capsys
    )
    assert code == 2 and "--devices 999" in err


def test_cli_methods_filter_and_skip(tmp_path, probs, fake_engine, capsys):
    out = tmp_path / "out"
    args = ["--all", "--problems", probs[0], "--methods", "tql", "--out", str(out)]
    code, err = _cli(
        [*args, "--trials", "1", "--rollouts", "1", "--horizon", "50"], capsys
    )
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["case_study", "main"]
    runs = pd.read_parquet(out / "main/runs.parquet")
    assert set(runs.method) == {"tql"}


def test_dry_run_prints_plan(tmp_path, probs, fake_engine, capsys):
    args = ["--experiment", "prior_strength", "--problems", probs[0], "--dry-run"]
    code = sweep.main([*args, "--out", str(tmp_path), "--trials", "3"])
    out = capsys.readouterr().out
    assert code == 0 and "prior_strength: 1 object(s)" in out
    assert "180 rollouts to run" in out
    assert not fake_engine and not (tmp_path / "prior_strength").exists()
    # the dry run says what the run will do: nothing once complete, with or
    # without the chunk folders (a fresh clone of committed results)
    assert sweep.main([*args[:-1], "--out", str(tmp_path), "--trials", "3"]) == 0
    for _ in range(2):
        code = sweep.main([*args, "--out", str(tmp_path), "--trials", "3"])
        out = capsys.readouterr().out
        assert code == 0 and "complete in" in out and "compute nothing" in out
        shutil.rmtree(tmp_path / "prior_strength" / "chunks", ignore_errors=True)
    code = sweep.main([*args, "--out", str(tmp_path), "--trials", "2"])
    assert code == 0 and "another configuration" in capsys.readouterr().out


def test_dry_run_does_not_build_missing_problems(tmp_path, monkeypatch, capsys):
    import precompute

    built = []
    monkeypatch.setattr(
        sweep.experiments, "_missing_problems", lambda names, params=None: list(names)
    )
    monkeypatch.setattr(precompute, "ensure", lambda *a, **k: built.append(a))
    args = ["--experiment", "prior_strength", "--dry-run", "--out", str(tmp_path)]
    code = sweep.main([*args, "--problem-source", "built"])
    out = capsys.readouterr().out
    assert code == 0 and not built
    assert "prior_strength: 1 problem file(s) missing" in out and "bar_clamp" in out
    assert not (tmp_path / "prior_strength").exists()


def test_catalog_names_resolve_in_catalogue_order():
    catalog = pytest.importorskip("precompute.catalog")
    got = sweep.experiments._resolve_names(["C3", "dexnet_adv", "bar_clamp"], catalog)
    names = [n for n, _, _ in got]
    assert names[:13] == [i.name for i in catalog.objects("dexnet_adv")]
    assert names[13:] == ["C3"] and len(set(names)) == 14
    assert [oid for _, _, oid in got] == sorted(oid for _, _, oid in got)
    assert {s for _, s, _ in got} == {"dexnet_adv", "egad_eval"}
    with pytest.raises(sweep.SweepError, match="did you mean bar_clamp"):
        sweep.experiments._resolve_names(["bar_clam"], catalog)
    # Every object named by an experiment exists.
    for name in experiments.EXPERIMENTS:
        mod = experiments.get(name)
        if getattr(mod, "GENERATED", ()):  # its objects are its generated problems
            continue
        sweep.experiments._resolve_names(
            list(mod.OBJECTS) + list(mod.SMOKE_OBJECTS), catalog
        )


def test_result_files_are_readable_by_others(tmp_path):
    old = os.umask(0o022)
    try:
        p = results.atomic_write_parquet(
            pd.DataFrame({"a": [1]}), tmp_path / "t.parquet"
        )
        j = results.atomic_write_json({"a": 1}, tmp_path / "m.json")
    finally:
        os.umask(old)
    for f in (p, j):
        assert stat.S_IMODE(os.stat(f).st_mode) == 0o644


# ------------------------------------------------------------------------ reuse
_CLEAN = {"commit": "c0ffee" * 6 + "c0ff", "dirty": False}


def test_identical_rollouts_are_copied_from_another_experiment(
    tmp_path, probs, fake_engine, capsys, monkeypatch
):
    """early_stopping repeats main's LEGS runs (same keys, same checks): with a
    clean commit they are copied, not computed, and the tables are byte-identical
    to computing them; chunks that record active sets (case_study's LEGS) still
    run; a dirty tree, another commit or --no-reuse computes everything."""
    monkeypatch.setattr(sweep.store, "_git_commit", lambda: dict(_CLEAN))
    base = ["--problems", *probs, "--trials", "2", "--rollouts", "2"]
    base += ["--horizon", "200", "--methods", "legs", "tql"]
    exps = ["--experiment", "main", "case_study", "early_stopping"]

    code, err = _cli(
        [*base, *exps, "--out", str(tmp_path / "ref"), "--no-reuse"], capsys
    )
    assert code == 0, err
    computed_all = len(fake_engine)

    fake_engine.clear()
    out = tmp_path / "res"
    code, err = _cli([*base, *exps, "--out", str(out)], capsys)
    assert code == 0, err
    ref = _read_all(tmp_path / "ref")
    assert _read_all(out) == ref and any("early_stopping" in k for k in ref)
    es = json.loads((out / "early_stopping/manifest.json").read_text())
    assert es["sessions"][-1]["chunks_computed"] == 0
    assert es["sessions"][-1]["chunks_reused"] == es["chunks_total"] > 0
    assert all(c["reused_from"] for c in es["chunks"].values())
    assert all(
        r.startswith("main/") for c in es["chunks"].values() for r in c["reused_from"]
    )
    cs = json.loads((out / "case_study/manifest.json").read_text())
    legs = [c for c in cs["chunks"] if c.startswith("legs__")]
    tql = [c for c in cs["chunks"] if c.startswith("tql__")]
    assert legs and tql
    assert all(not cs["chunks"][c]["reused_from"] for c in legs)  # active sets
    assert all(cs["chunks"][c]["reused_from"] for c in tql)
    assert len(fake_engine) == computed_all - es["chunks_total"] - len(tql)

    # Donors must come from the same clean commit as the running code.
    for git in ({**_CLEAN, "dirty": True}, {**_CLEAN, "commit": "beef" * 10}):
        monkeypatch.setattr(sweep.store, "_git_commit", lambda git=git: dict(git))
        fake_engine.clear()
        code, err = _cli(
            [*base, "--experiment", "early_stopping", "--out", str(out), "--overwrite"],
            capsys,
        )
        assert code == 0, err
        assert len(fake_engine) == es["chunks_total"]
        assert _read_all(out) == ref


def test_reuse_needs_the_same_problem_file_and_configuration(
    tmp_path, fake_engine, capsys, monkeypatch
):
    monkeypatch.setattr(sweep.store, "_git_commit", lambda: dict(_CLEAN))
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = _problems(tmp_path / "a", [("alpha", 3, 200)])
    # Another file under the same name (made from another seed).
    b = _problems(tmp_path / "b", [("gamma", 3, 200), ("alpha", 4, 200)])[1:]

    def engine_calls(experiment, files, horizon, *extra):
        fake_engine.clear()
        args = ["--experiment", experiment, "--problems", *files, "--trials", "1"]
        args += ["--rollouts", "2", "--methods", "legs", "--horizon", str(horizon)]
        code, err = _cli([*args, "--out", str(tmp_path / "out"), *extra], capsys)
        assert code == 0, err
        return len(fake_engine)

    assert engine_calls("main", a, 200) == 1
    assert engine_calls("early_stopping", b, 200) == 1  # another file
    assert engine_calls("early_stopping", a, 100, "--overwrite") == 1  # another H
    assert engine_calls("early_stopping", a, 200, "--overwrite") == 0  # copied


def test_shape_buckets_trade_programs_for_padding():
    """Fewer pose buckets compile fewer programs and pad more poses (the work
    run also counts the padded rows of the mini-batches, whatever the buckets)."""
    from legs_jax.sweep import shapes

    objects = [
        _obj(f"o{p}", p, 120, oid=i) for i, p in enumerate((2, 3, 5, 7, 9, 12, 17, 30))
    ]
    arms = [("legs", "", {}), ("borges_2000", "", {}), ("tql", "", {})]

    def make_plans():
        plan = _plan(objects, arms, trials=10, rollouts=10)
        plan.chunks = sweep.plan_chunks(plan)
        return [plan]

    rows = {r["buckets"]: r for r in shapes.tradeoff(make_plans, n_dev=2)}
    none = rows["none (every pose count its own)"]
    adopted = rows["8, 16, 32 (adopted)"]
    one = rows["32"]
    assert none["programs"] > adopted["programs"] > one["programs"] >= 3
    assert min(r["work"] for r in rows.values()) >= 1.0
    assert adopted["work"] < one["work"]
    # every pose count of the catalogue's range lands in a bucket that holds it
    assert [sweep.plan._pose_bucket(p) for p in (1, 8, 9, 16, 17, 32, 33, 70)] == [
        8,
        8,
        16,
        16,
        32,
        32,
        64,
        96,
    ]


def test_projection_by_chunk_charges_each_bucket_its_rate_and_copies_nothing():
    """The benchmark's projection runs over the sweep's chunks: each pose bucket
    at its own rates (linear in 1/rate), never below the real rollouts' work, and
    an experiment whose chunks repeat an earlier one's rollouts costs nothing."""
    from legs_jax import bench

    objects = [_obj(f"o{p}", p, 120, oid=i) for i, p in enumerate((5, 7, 12, 14))]
    arms = [("legs", "", {}), ("borges_2000", "", {})]
    main = _plan(objects, arms, trials=4, rollouts=5)
    main.chunks = sweep.plan_chunks(main)
    again = _plan(objects[:3], arms, trials=4, rollouts=5)
    again.name = "again"
    again.chunks = sweep.plan_chunks(again)
    other = _plan(objects[:3], arms, trials=4, rollouts=5)
    other.name, other.seed = "other", 1
    other.chunks = sweep.plan_chunks(other)
    assert {c.num_poses for c in main.chunks} == {8, 16}
    r8 = {"legs": 1e5, "borges_2000": 1e4}

    def minutes(r16, plans=(main,)):
        return bench.projection_by_chunk({8: r8, 16: r16}, list(plans), 2)[
            "projected_all_minutes"
        ]

    r16 = {"legs": 5e4, "borges_2000": 4e3}
    slow = {k: v / 2 for k, v in r16.items()}
    free = {k: 1e30 for k in r16}
    both, only8 = minutes(r16), minutes(free)
    assert 0 < only8 < both
    assert minutes(slow) == pytest.approx(only8 + 2 * (both - only8), rel=1e-3)
    real = sum(  # the real rollouts of every chunk, no padding
        c.rollouts
        * main.horizon
        / {8: r8, 16: r16}[c.num_poses][main.arms[c.arm].method]
        for c in main.chunks
    )
    assert both * 60 >= real * (1 - 1e-3)
    # a repeat of main's rollouts is copied; another seed is computed
    assert minutes(r16, (main, again)) == pytest.approx(both, rel=1e-3)
    assert minutes(r16, (main, other)) > both * 1.5
    p = bench.projection_by_chunk({8: r8, 16: r16}, [main, again, other], 2)
    assert p["projected_minutes_per_experiment"]["again"] == 0


def test_repeated_list_options_add_up():
    """A list option given twice keeps both (argparse's default
    would keep only the last and run another grid without a word)."""
    p = sweep.cli.build_parser()
    a = p.parse_args(
        ["--experiment", "main", "--methods", "legs", "--methods", "tql"]
        + ["--grid", "delta=0.05,0.1", "--grid", "s=1,2"]
    )
    a = sweep.config.validate(sweep.SweepConfig.from_namespace(a))
    assert a.methods == ["legs", "tql"]
    assert a.grid == {"delta": (0.05, 0.05, 0.1, 0.1), "s": (1.0, 2.0, 1.0, 2.0)}
    a = p.parse_args(["--experiment", "main", "--experiment", "confidence"])
    assert a.experiment == ["main", "confidence"]


def test_a_grid_axis_given_twice_is_refused(capsys):
    p = sweep.cli.build_parser()
    a = p.parse_args(
        ["--experiment", "main", "--methods", "legs"]
        + ["--grid", "s=1", "--grid", "s=2"]
    )
    with pytest.raises(ConfigError, match="s given twice"):
        sweep.config.validate(sweep.SweepConfig.from_namespace(a))
    with pytest.raises(SystemExit) as e:
        sweep.main(
            ["--experiment", "main", "--methods", "legs"]
            + ["--grid", "s=1", "--grid", "s=2"]
        )
    assert e.value.code == 2 and "s given twice" in capsys.readouterr().err


@pytest.mark.parametrize("chunks", ["kept", "gone"])
@pytest.mark.parametrize("damage", ["overwrite", "delete_curves"])
def test_damaged_merged_table_is_merged_again(
    tmp_path, probs, fake_engine, capsys, damage, chunks
):
    """A merged table overwritten or lost is not reported complete:
    it is named in a warning and merged again from the chunks (or, where the
    chunks are gone, computed again); the tables then equal an undamaged run's."""
    base = ["--experiment", "confidence", "--problems", *probs, "--trials", "1"]
    base += ["--rollouts", "2", "--horizon", "100"]
    assert _cli([*base, "--out", str(tmp_path / "ref")], capsys)[0] == 0
    out = tmp_path / "out"
    assert _cli([*base, "--out", str(out)], capsys)[0] == 0
    d = out / "confidence"
    if damage == "overwrite":
        (d / "runs.parquet").write_bytes((d / "checks.parquet").read_bytes())
        name = "runs.parquet"
    else:
        (d / "curves.parquet").unlink()
        name = "curves.parquet"
    if chunks == "gone":
        shutil.rmtree(d / "chunks")
    code = sweep.main([*base, "--out", str(out), "--dry-run"])
    said = capsys.readouterr().out
    assert code == 0 and f"damaged ({name}" in said and "compute nothing" not in said
    calls = len(fake_engine)
    code = sweep.main([*base, "--out", str(out), "--compile-cache", "off"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"confidence: the merged tables in {d} are damaged ({name}" in err
    assert "complete in" not in err and "Traceback" not in err
    assert (len(fake_engine) > calls) == (chunks == "gone")
    assert _read_all(out) == _read_all(tmp_path / "ref")
    # whole again: the next run leaves every file as it is
    before = _files(out)
    assert _cli([*base, "--out", str(out)], capsys)[0] == 0
    assert _files(out) == before


def test_dry_run_with_overwrite_says_it_recomputes(
    tmp_path, probs, fake_engine, capsys
):
    """--dry-run --overwrite says what --overwrite does: every chunk
    computed again, not "complete ... compute nothing"."""
    args = ["--experiment", "prior_strength", "--problems", probs[0]]
    args += ["--out", str(tmp_path), "--trials", "3"]
    assert sweep.main([*args, "--quiet", "--compile-cache", "off"]) == 0
    capsys.readouterr()
    before = _files(tmp_path)
    code = sweep.main([*args, "--dry-run", "--overwrite"])
    said = capsys.readouterr().out
    assert code == 0 and "compute nothing" not in said
    assert "--overwrite: all" in said and "180 rollouts to run" in said
    assert "deleting the results in it first" in said
    assert _files(tmp_path) == before


@pytest.mark.parametrize(
    "args, folder",
    [
        (["--all"], "results"),
        (["--experiment", "main", "confidence"], "results"),
        (
            ["--experiment", "main", "--objects", "bar_clamp", "--methods", "legs,tql"],
            "runs/main-bar_clamp-legs+tql",
        ),
        (
            ["--experiment", "main", "--objects", "dexnet_adv", "--methods", "legs"]
            + ["--grid", "delta=0.01,0.05", "s=0,1"],
            "runs/main-dexnet_adv-legs-grid-delta+s",
        ),
        (["--experiment", "main", "--horizon", "500"], "runs/main-H500"),
        (["--all", "--seed", "3"], "runs/all-seed3"),
        (["--experiment", "main", "--problem-source", "built"], "runs/main-built"),
        (["--smoke"], "runs/smoke"),
        (
            ["--experiment", "main", "--methods", "legs,my_pkg.mine:METHOD"],
            "runs/main-legs+my_pkg.mine.METHOD",
        ),
    ],
)
def test_results_is_the_default_folder_of_the_declared_configuration_only(args, folder):
    a = sweep.config.validate(
        sweep.SweepConfig.from_namespace(sweep.cli.build_parser().parse_args(args))
    )
    assert sweep.config.default_out(a) == Path(folder)


def test_a_long_folder_name_is_cut_and_keeps_its_identity():
    names = [f"object_{i:02d}" for i in range(20)]
    a = sweep.SweepConfig(experiment=["main"], objects=names)
    out = sweep.config.default_out(a)
    assert out.parent == Path("runs") and len(out.name) <= 80
    b = sweep.SweepConfig(experiment=["main"], objects=[*names[:-1], "other"])
    assert sweep.config.default_out(b) != out


def test_a_users_sweep_writes_under_runs_and_never_touches_results(
    tmp_path, probs, fake_engine, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    args = ["--experiment", "main", "--problems", probs[0], "--methods", "tql"]
    code = sweep.main(
        [*args, "--trials", "1", "--rollouts", "1", "--horizon", "50"]
        + ["--compile-cache", "off"]
    )
    err = capsys.readouterr().err
    assert code == 0
    folder = Path("runs/main-alpha-tql-T1-R1-H50")
    assert f"results go to {folder}/" in err
    assert (tmp_path / folder / "main" / "runs.parquet").is_file()
    assert not (tmp_path / "results").exists()


def test_a_mesh_given_as_a_problem_names_the_command_that_builds_one(tmp_path, capsys):
    mesh = tmp_path / "duck.obj"
    mesh.write_text("v 0 0 0\n")
    with pytest.raises(SystemExit) as e:
        sweep.main(["--problems", str(mesh)])
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert "is a mesh" in err and f"python -m precompute --mesh {mesh}" in err
    assert "pickle" not in err and "Traceback" not in err


def test_a_sweep_runs_from_python(tmp_path, probs, fake_engine):
    where = dict(
        trials=1,
        rollouts=2,
        horizon=50,
        out=str(tmp_path / "mine"),
        quiet=True,
        compile_cache="off",
    )
    out = sweep.run(problems=[probs[0]], methods=["tql", "legs"], **where)
    assert out == tmp_path / "mine"
    runs = pd.read_parquet(out / "main" / "runs.parquet")
    assert set(runs.method) == {"tql", "legs"} and len(runs) == 2 * 2
    assert json.loads((out / "main" / "manifest.json").read_text())["status"] == (
        "complete"
    )
    # the same configuration again: complete, nothing recomputed
    calls = len(fake_engine)
    again = sweep.run(
        sweep.SweepConfig(problems=[probs[0]], methods=["tql", "legs"]), **where
    )
    assert again == out and len(fake_engine) == calls
    with pytest.raises(ConfigError, match="unknown method 'leg'.*did you mean legs"):
        sweep.run(experiment=["main"], methods=["leg"])
    with pytest.raises(ConfigError, match="nothing to run"):
        sweep.run()


def test_the_configuration_names_the_beta_sampler():
    """A result's configuration (and with it the config hash, so chunk reuse)
    names the Beta sampler of the Thompson methods' draws."""
    from legs_jax.core import beta_sampler

    cfg = _plan([_obj("a", 4, 200)], [("legs", "", {})]).config()
    assert cfg["beta_sampler"] == beta_sampler.SAMPLER_VERSION
    assert cfg["beta_sampler"] != beta_sampler.PREVIOUS_SAMPLER_VERSION
