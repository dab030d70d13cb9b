"""A method from the user's own module, outside the package, end to end: the
example file of docs/methods.md, written to a temporary package, runs through the sweep
CLI beside LEGS (conformance checks first), its rows carry its own
hyperparameter column, and they equal what ``runtime.run`` gives for the same
method named the same way. A module whose attribute is not a method, or whose
method breaks the contract, is refused in one line."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from legs_jax import runtime, sweep, synthetic
from legs_jax.core import keys, methods, problem

ROOT = Path(__file__).resolve().parents[1]


def _docs_method() -> str:
    text = (ROOT / "docs" / "methods.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    (code,) = [b for b in blocks if "METHOD = Method(" in b]
    return code


@pytest.fixture
def user_package(tmp_path, monkeypatch):
    pkg = tmp_path / "user_src" / "my_pkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "my_method.py").write_text(_docs_method())
    (pkg / "broken.py").write_text("METHOD = 'not a method'\n")
    monkeypatch.syspath_prepend(str(tmp_path / "user_src"))
    # a my_pkg imported by an earlier test lives in another folder: forget it
    for name in [m for m in sys.modules if m == "my_pkg" or m.startswith("my_pkg.")]:
        monkeypatch.delitem(sys.modules, name)
    # the methods a test registers are forgotten after it (tests in any order)
    monkeypatch.setattr(methods, "_REGISTRY", dict(methods._REGISTRY))
    return pkg


def test_user_method_runs_through_the_sweep_cli(tmp_path, user_package, capsys):
    pb = synthetic.make_problem(seed=4, num_poses=3, num_grasps=150, num_trials=1)
    path = tmp_path / "part.npz"
    problem.save(pb, path)
    out = tmp_path / "out"
    args = ["--problems", str(path), "--methods", "legs,my_pkg.my_method:METHOD"]
    args += ["--trials", "1", "--rollouts", "2", "--horizon", "120", "--quiet"]
    args += ["--out", str(out), "--compile-cache", "off", "--devices", "1"]
    assert sweep.main(args) == 0, capsys.readouterr().err
    runs = pd.read_parquet(out / "main" / "runs.parquet")  # no --experiment: main
    assert list(runs.method.unique()) == ["legs", "eps_greedy"]
    mine = runs[runs.method == "eps_greedy"]
    assert (mine["explore"] == 0.1).all() and runs.loc[
        runs.method == "legs", "explore"
    ].isna().all()
    assert list(runs.columns).index("explore") == list(runs.columns).index("eta") + 1
    curves = pd.read_parquet(out / "main" / "curves.parquet")
    assert set(curves.method) == {"legs", "eps_greedy"}
    # the same rollouts from Python, the method named the same way
    r = runtime.run(
        problem.stack([pb]),
        "my_pkg.my_method:METHOD",
        object_ids=[int(keys.object_id_from_name(pb.name))],
        num_rollouts=2,
        horizon=120,
        progress=False,
    )
    np.testing.assert_array_equal(mine.final_gap.to_numpy(), r.final_gap.reshape(-1))
    np.testing.assert_array_equal(mine.successes.to_numpy(), r.successes.reshape(-1))
    assert np.all(r.final_gap >= 0) and r.successes.min() > 0

    # a second run finds it complete; a grid over its own hyperparameter runs
    assert sweep.main(args) == 0
    grid = [*args[:-6], "--out", str(tmp_path / "grid"), "--compile-cache", "off"]
    grid += ["--devices", "1", "--grid", "explore=0.0,0.5"]
    assert sweep.main(grid) == 0, capsys.readouterr().err
    g = pd.read_parquet(tmp_path / "grid" / "main" / "runs.parquet")
    assert sorted(g.loc[g.method == "eps_greedy", "explore"].unique()) == [0.0, 0.5]
    assert (g.loc[g.method == "legs", "delta"] == 0.05).all()


def test_a_bad_user_method_is_refused_in_one_line(tmp_path, user_package, capsys):
    pb = synthetic.make_problem(seed=4, num_poses=3, num_grasps=150, num_trials=1)
    path = tmp_path / "part.npz"
    problem.save(pb, path)
    base = ["--problems", str(path), "--trials", "1", "--out", str(tmp_path / "o")]
    for spec, says in [
        ("my_pkg.broken:METHOD", "not a legs_jax.core.methods.base.Method"),
        ("my_pkg.nowhere:METHOD", "cannot import my_pkg.nowhere"),
        ("my_pkg.my_method:NOPE", "has no attribute NOPE"),
    ]:
        assert sweep.main([*base, "--methods", spec]) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1, err
    assert sweep.main([*base, "--methods", "legs", "--grid", "explore=0.1"]) == 2
    assert "explore is not a hyperparameter of legs" in capsys.readouterr().err


def test_a_method_selecting_an_out_of_range_grasp_is_refused_in_one_line(
    tmp_path, user_package, capsys
):
    """A grasp id past the tables (here 1999 of 160) is refused by
    the conformance check in one line, as NaN estimates are, not an IndexError."""
    code = (
        _docs_method()
        .replace(
            "    return grasp, grasp, None",
            "    grasp = jnp.full_like(grasp, 1999)\n    return grasp, grasp, None",
        )
        # a name of its own: the docs' method may be registered already
        .replace('name="eps_greedy"', 'name="eps_far"')
    )
    assert code != _docs_method()
    (user_package / "far.py").write_text(code)
    pb = synthetic.make_problem(seed=4, num_poses=3, num_grasps=150, num_trials=1)
    path = tmp_path / "part.npz"
    problem.save(pb, path)
    args = ["--problems", str(path), "--trials", "1", "--out", str(tmp_path / "o")]
    assert sweep.main([*args, "--methods", "my_pkg.far:METHOD", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "fails its conformance check" in err and "grasp 1999, outside 0..159" in err
    assert not (tmp_path / "o").exists()
