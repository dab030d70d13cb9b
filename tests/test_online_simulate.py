"""The simulated robot's command line: a resumed run keeps its own
length and curve step, the learning curve has enough marked points, and a
problem file or a mesh of the user's own runs as well as a catalogue name."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import trimesh

from legs_jax.core import problem as problem_mod
from legs_jax.online import cli
from legs_jax.online import simulate as sim_mod
from precompute import cli as precompute_cli


def _curve(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "curve.jsonl").read_text().splitlines()]


def test_resume_keeps_the_runs_steps_and_curve_step(
    tmp_path, clamp_problem, monkeypatch, capsys
):
    """A run of 120 steps with a curve point every 30, killed at
    step 29 and resumed without --steps or --eval-every, ends at 120 with its
    points every 30 (not at the defaults 1000 and 100)."""
    out = tmp_path / "run"
    args = ["simulate", "--problem", str(clamp_problem), "--given-poses"]
    args += ["--out", str(out), "--quiet", "--compile-cache", "off"]
    real = sim_mod.Simulation.run_step
    done = {"n": 0, "stop": 29}

    def run_step(self):
        if done["n"] >= done["stop"]:
            raise KeyboardInterrupt  # the kill
        done["n"] += 1
        return real(self)

    monkeypatch.setattr(sim_mod.Simulation, "run_step", run_step)
    assert cli.main([*args, "--steps", "120", "--eval-every", "30"]) == 130
    capsys.readouterr()
    done["stop"] = 200  # a resume that ran on towards 1000 stops here
    assert cli.main([*args, "--resume"]) == 0, capsys.readouterr().err
    assert done["n"] == 120
    assert [r["step"] for r in _curve(out)] == [0, 30, 60, 90, 120]
    assert "120 grasps" in capsys.readouterr().out
    # a longer run asked for on resume goes on, and keeps that length after
    assert cli.main([*args, "--resume", "--steps", "150"]) == 0
    assert json.loads((out / "simulation.json").read_text())["steps"] == 150
    assert [r["step"] for r in _curve(out)][-2:] == [120, 150]


def test_learning_curve_has_marked_points(tmp_path, clamp_problem, monkeypatch):
    """The default curve step gives 50 points over a short run (not
    4 points at every 100 steps), each drawn with a marker."""
    out = tmp_path / "run"
    drawn = {}

    def save(fig, ax, title, path):
        drawn["lines"] = [(ln.get_marker(), len(ln.get_xdata())) for ln in ax.lines]
        return Path(path)

    monkeypatch.setattr(sim_mod, "save_figure", save)
    args = ["simulate", "--problem", str(clamp_problem), "--given-poses"]
    args += ["--out", str(out), "--quiet", "--steps", "200"]
    assert cli.main([*args, "--compile-cache", "off"]) == 0
    steps = [r["step"] for r in _curve(out)]
    assert steps == list(range(0, 201, 4))
    assert len(drawn["lines"]) == 4  # success rate, gap, the paper's bound, ours
    assert all(m not in (None, "", "None") and n == 51 for m, n in drawn["lines"])


def _in_process(args, cwd, monkeypatch, capsys) -> subprocess.CompletedProcess:
    """``python -m MODULE ARGS`` in ``cwd``, run as the module's ``main`` here."""
    mains = {"precompute": precompute_cli.main, "legs_jax.online": cli.main}
    monkeypatch.chdir(cwd)
    capsys.readouterr()
    try:
        code = mains[args[0]](list(args[1:]))
    except SystemExit as e:  # argparse errors
        code = e.code
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


def test_a_users_mesh_is_skipped_when_current_and_simulated(
    tmp_path, monkeypatch, capsys
):
    """python -m precompute --mesh skips an up-to-date file (unless --force),
    and online simulate runs on that problem file or on the mesh itself (both
    command lines called in this process, as their ``main``)."""

    def _run(args, cwd):
        return _in_process(args, cwd, monkeypatch, capsys)

    work = tmp_path / "work"
    work.mkdir()
    trimesh.creation.box((40.0, 60.0, 30.0)).export(work / "box.stl")
    build = ["precompute", "--mesh", "box.stl", "--units", "mm", "--trials", "1"]
    build += ["--grasps", "100", "--samples", "5", "--quiet", "--prior", "synthetic"]
    r = _run(build, work)
    assert r.returncode == 0, r.stderr
    dest = work / "problems" / "custom" / "box.npz"
    stamp = dest.stat().st_mtime_ns
    r = _run(build, work)
    assert r.returncode == 0, r.stderr
    assert (
        "1 up-to-date problem file(s) skipped" in r.stdout and "built" not in r.stdout
    )
    assert dest.stat().st_mtime_ns == stamp
    r = _run([*build, "--force"], work)
    assert r.returncode == 0 and "built 1 problem file(s)" in r.stdout
    assert dest.stat().st_mtime_ns != stamp
    # the problem file: the mesh found where it was built from
    sim = ["legs_jax.online", "simulate", "--quiet", "--compile-cache", "off"]
    r = _run([*sim, "--object", str(dest), "--given-poses", "--steps", "5",
              "--out", "run1"], tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "5 grasps" in r.stdout and "gap" in r.stdout
    # the mesh itself: poses from the mesh, recognition, no gap
    r = _run([*sim, "--object", "box.stl", "--units", "mm", "--steps", "2",
              "--reservoir", "200", "--out", "run2"], work)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "2 grasps" in r.stdout and "gap" not in r.stdout
    # a mesh without its unit, and a problem file whose mesh is gone: one line
    r = _run([*sim, "--object", "box.stl", "--out", "run3"], work)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0
    assert "needs --units" in r.stderr
    (work / "box.stl").rename(work / "moved.stl")
    r = _run([*sim, "--object", str(dest), "--out", "run4"], tmp_path)
    assert (
        r.returncode == 2 and "give it as --object MESH beside --problem" in r.stderr
    ), r.stderr
    assert r.stderr.strip().count("\n") == 0
    assert np.isfinite(problem_mod.load(dest).landing).all()


def test_a_catalogue_object_runs_on_the_shipped_problem(tmp_path, monkeypatch, capsys):
    """On a fresh clone (no problem built on this machine) the README's
    ``simulate --object bar_clamp --given-poses`` runs on the shipped file; a
    trial whose grasp geometry the shipped set leaves out is refused in one line."""
    import precompute.build

    monkeypatch.setattr(precompute.build, "problems_dir", lambda: tmp_path / "none")
    args = ["simulate", "--object", "bar_clamp", "--given-poses", "--quiet"]
    args += ["--compile-cache", "off", "--steps", "20", "--eval-every", "10"]
    assert cli.main([*args, "--out", str(tmp_path / "a")]) == 0, capsys.readouterr()
    out = capsys.readouterr().out
    assert "20 grasps" in out and "gap" in out  # the shipped file's p* gives a gap
    # the pose given, the success rate is the problem's own p: exact, and said so
    assert "true success rate of the recommendations" in out
    curve = _curve(tmp_path / "a")
    assert [r["step"] for r in curve] == [0, 10, 20]
    assert all(0 <= r["performance"] <= 1 for r in curve)
    rc = cli.main([*args, "--trial", "3", "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert rc == 2 and "trial 3" in err and "precompute --objects bar_clamp" in err
    assert "Traceback" not in err and not (tmp_path / "b").exists()


def test_the_success_rate_is_called_an_estimate_in_full_perception():
    """Without the true pose the curve's success rate is estimated from
    EVAL_SAMPLES perturbed executions of each pose's recommended grasp, and the
    printed lines say so; with the pose given it is the problem's exact p."""
    from types import SimpleNamespace

    assert cli._rate(SimpleNamespace(given=True)) == (
        "true success rate of the recommendations"
    )
    said = cli._rate(SimpleNamespace(given=False))
    assert "true" not in said and f"estimated from {sim_mod.EVAL_SAMPLES}" in said
