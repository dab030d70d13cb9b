"""Warnings where an online result means little: a pose without any success after
NO_SUCCESS_ATTEMPTS attempts, recognition that has seen one pose only after
ONE_POSE_STEPS steps, a simulated run without a success, and a problem file with
poses where no grasp can succeed. They go to stderr, never into serve's JSON."""

from __future__ import annotations

import dataclasses
import io
import json
import re

import numpy as np
import pytest

from legs_jax.core import problem as problem_mod
from legs_jax.online import Intrinsics, Session, cli
from legs_jax.online import session as session_mod
from legs_jax.online import simulate as sim_mod
from legs_jax.online.protocol import serve
from legs_jax.online.robot import SimRobot

N = session_mod.NO_SUCCESS_ATTEMPTS
K = 200  # reservoir size of the sessions here
INTR = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)


def given_poses(P=2, seed=0):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, K)
    return {
        s: {
            "center": rng.normal(0, 0.01, (K, 3)),
            "axis": np.stack([np.cos(a), np.sin(a), np.zeros(K)], 1),
            "width": np.full(K, 0.03),
            "q": rng.uniform(0, 1, K),
            "valid": np.ones(K, bool),
        }
        for s in range(P)
    }


def _attempt(ses, pose, success):
    ses.observe(pose=pose)
    ses.ask()
    ses.tell(success)
    return ses.take_warnings()


def test_a_pose_without_success_warns_once(tmp_path):
    """Pose 0 fails every time: one warning at attempt N, naming the pose and N,
    none before or after; pose 1, with one success, fails as often unwarned."""
    assert 10 <= N <= 200
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        for i in range(N - 1):
            assert _attempt(ses, 0, False) == [], i
        (w,) = _attempt(ses, 0, False)
        assert f"pose 0 has had no success in {N} grasp attempts" in w
        assert all(_attempt(ses, 0, False) == [] for _ in range(5))
        assert _attempt(ses, 1, True) == []
        assert all(_attempt(ses, 1, False) == [] for _ in range(N + 5))


def test_serve_writes_warnings_to_stderr_not_into_the_protocol(tmp_path):
    reqs = []
    for i in range(N):
        reqs += [{"id": 3 * i, "cmd": "observe", "pose": 1}, {"cmd": "ask"}]
        reqs.append({"id": 3 * i + 2, "cmd": "tell", "success": False})
    stdin = io.StringIO("\n".join(json.dumps(r) for r in reqs) + "\n")
    stdout, stderr = io.StringIO(), io.StringIO()
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        serve(ses, stdin, stdout, stderr)
    out = [json.loads(line) for line in stdout.getvalue().splitlines()]
    assert len(out) == 1 + len(reqs) and all(r["ok"] for r in out)
    (line,) = stderr.getvalue().splitlines()
    assert line.startswith("warning: pose 1 ") and f" {N} " in line


def test_recognition_of_one_pose_only_warns_once(tmp_path, box, monkeypatch):
    """A box that always lands on the same face: after ONE_POSE_STEPS steps (3
    here, to keep the test short) one warning; a session with given poses, which
    has no recognition, never gives it."""
    monkeypatch.setattr(session_mod, "ONE_POSE_STEPS", 3)
    rob = SimRobot(box, np.random.default_rng(0), intrinsics=INTR)
    got = []
    with Session.create(tmp_path / "s", reservoir_size=K, prior="geometric") as ses:
        for _ in range(5):
            rob.place()
            ses.observe(rob.render(), INTR)
            ses.ask()
            ses.tell(True)
            got.append(ses.take_warnings())
    assert [len(w) for w in got] == [0, 0, 1, 0, 0]
    assert "recognition has seen one pose only in 3 steps" in got[2][0]
    with Session.create(tmp_path / "g", given_poses=given_poses(P=1)) as ses:
        assert not any(_attempt(ses, 0, True) for _ in range(5))


def test_simulate_warns_of_dead_poses_before_the_run(tmp_path, clamp_problem, capsys):
    """A problem file in which no grasp of one pose can succeed: a warning line
    naming that pose, before any grasp (the run is killed at its first step);
    the other poses are not named."""
    pb = problem_mod.load(clamp_problem)
    dead = int(np.flatnonzero(pb.pose_valid)[0])
    rob = pb.robustness.copy()
    rob[:, dead] = 0.0
    path = problem_mod.save(dataclasses.replace(pb, robustness=rob), tmp_path / "d.npz")

    def killed(self):
        raise KeyboardInterrupt

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sim_mod.Simulation, "run_step", killed)
        args = ["simulate", "--problem", str(path), "--given-poses", "--quiet"]
        rc = cli.main([*args, "--compile-cache", "off", "--out", str(tmp_path / "r")])
    assert rc == 130
    err = capsys.readouterr().err
    named = re.findall(r"^warning: the problem of bar_clamp: pose (\d+) ", err, re.M)
    assert named == [str(dead)], err
    assert "no grasp that can succeed in 1 of 1 trial(s)" in err


@pytest.mark.slow  # ~45 s on 2 busy cores, most of it compiling
def test_simulate_without_any_success_warns(tmp_path, clamp_problem, capsys):
    """A gripper that never lifts the object: the pose warning at attempt N and,
    at the end, a warning that the run had no success; the --help states N."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SimRobot, "success", lambda self, c, a, samples=1: False)
        args = ["simulate", "--problem", str(clamp_problem), "--given-poses"]
        args += ["--quiet", "--compile-cache", "off", "--steps", str(N + 10)]
        assert cli.main([*args, "--out", str(tmp_path / "r")]) == 0
    cap = capsys.readouterr()
    assert "0 successes" in cap.out
    lines = [x for x in cap.err.splitlines() if x.startswith("warning: ")]
    assert any(f"no success in {N} grasp attempts" in x for x in lines), cap.err
    assert lines[-1].startswith(f"warning: no success in {N + 10} grasp attempts")
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--help"])
    assert f"no success in {N} grasp attempts" in " ".join(
        capsys.readouterr().out.split()
    )
