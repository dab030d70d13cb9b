"""Verified stopping in the online session: a phase asks for the frozen
recommendations, its attempts go to the test and not to the method, it ends
certified or refuted, and a reopened session has the same verification."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from test_online import given_poses

from legs_jax.online import InputError, OrderError, Session
from legs_jax.online.protocol import serve


def _explore(ses, steps, rng, p_ok=0.7):
    for _ in range(steps):
        ses.observe(pose=int(rng.integers(3)))
        ses.ask()
        ses.tell(bool(rng.random() < p_ok))


def _attempt(ses, pose, ok):
    ses.observe(pose=pose)
    a = ses.ask()
    return a, ses.tell(ok)


def test_a_phase_tries_the_frozen_recommendations_and_certifies(tmp_path):
    rng = np.random.default_rng(0)
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        _explore(ses, 60, rng)
        rec = ses.loop.recommendation().copy()
        est = [x.copy() for x in ses.loop.estimates()]
        state = ses.verify(0.6)
        assert state["open"] and state["phase"] == 1 and state["level"] == 0.025
        assert ses.verify(0.6) == state  # idempotent while open
        verdicts, landings = [], 0
        for i in range(200):
            pose = i % 3
            landings += ses._landing  # this observation is a landing (a drop)
            a, told = _attempt(ses, pose, True)
            assert a["verify"] and a["grasp"] == rec[pose]
            verdicts.append(told["verification"]["verdict"])
            if verdicts[-1] is not None:
                break
        # every attempt succeeded: certified, after as many as the test needs;
        # only attempts after a landing are in the test (the first may follow a
        # failure of the exploration, the object toppled, not dropped)
        assert verdicts[-1] == "certified" and set(verdicts[:-1]) == {None}
        assert ses.stopped["step"] == 60 + len(verdicts) == ses.step
        assert ses.stopped["attempts"] == landings
        assert len(verdicts) - 1 <= landings <= len(verdicts)
        # the method learnt nothing from the attempts
        np.testing.assert_array_equal(ses.loop.recommendation(), rec)
        for x, y in zip(ses.loop.estimates(), est, strict=True):
            np.testing.assert_array_equal(x, y)
        # after the stop, asks explore again and verify changes nothing
        _, told = _attempt(ses, 0, False)
        assert "verification" not in told
        assert ses.verify(0.6)["stopped"] == ses.stopped
        log = (tmp_path / "s" / "log.jsonl").read_text()
        before = ses.verification_state()
    with Session.open(tmp_path / "s") as again:
        assert again.verification_state() == before
        assert again.stopped == before["stopped"]
    assert (tmp_path / "s" / "log.jsonl").read_text() == log


def test_a_refuted_phase_hands_back_to_exploration_and_the_next_spends_less(tmp_path):
    rng = np.random.default_rng(1)
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        _explore(ses, 30, rng)
        ses.verify(0.9)
        verdict, tested = None, []
        for i in range(400):
            # fail after every landing, succeed where the object toppled: the
            # test sees failures only (the successes drop the object again)
            landing = ses._landing
            _, told = _attempt(ses, i % 3, not landing)
            tested.append(landing)
            verdict = told["verification"]["verdict"]
            if verdict is not None:
                break
        assert told["verification"]["attempts"] == sum(tested)
        assert verdict == "refuted" and ses.stopped is None and not ses.verifying
        a = (ses.observe(pose=0), ses.ask())[1]
        assert "verify" not in a  # exploring: the method's own choice
        ses.tell(True)
        state = ses.verify(0.9)
        assert state["phase"] == 2 and state["level"] == pytest.approx(0.05 / 6)
        # a run tests one threshold
        with pytest.raises(InputError, match="one threshold|another threshold"):
            ses.verify(0.8)


def test_verify_refuses_bad_input_and_a_pending_grasp(tmp_path):
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        for bad in (0.0, 1.0, 1.5, "0.8", True):
            with pytest.raises(InputError, match="rho_min"):
                ses.verify(bad)
        with pytest.raises(InputError, match="delta"):
            ses.verify(0.8, delta=0)
        ses.observe(pose=0)
        ses.ask()
        with pytest.raises(OrderError, match="pending"):
            ses.verify(0.8)
        assert ses.verification_state() is None


def test_the_protocol_verifies(tmp_path):
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        reqs = [
            {"id": 1, "cmd": "observe", "pose": 0},
            {"id": 2, "cmd": "ask"},
            {"id": 3, "cmd": "tell", "success": True},
            {"id": 4, "cmd": "verify", "rho_min": 0.5},
            {"id": 5, "cmd": "observe", "pose": 1},
            {"id": 6, "cmd": "ask"},
            {"id": 7, "cmd": "tell", "success": True},
            {"id": 8, "cmd": "verify"},
            {"id": 9, "cmd": "verify", "rho_min": 0.5, "level": 2},
            {"id": 10, "cmd": "quit"},
        ]
        out = io.StringIO()
        serve(ses, io.StringIO("".join(json.dumps(r) + "\n" for r in reqs)), out)
    got = {r.get("id"): r for r in map(json.loads, out.getvalue().splitlines())}
    assert got[4]["ok"] and got[4]["result"]["open"]
    assert got[6]["result"]["verify"] is True
    assert got[7]["result"]["verification"]["attempts"] == 1
    assert not got[8]["ok"] and "rho_min" in got[8]["error"]["message"]
    assert not got[9]["ok"] and "level" in got[9]["error"]["message"]


def test_simulate_refuses_verify_without_a_threshold(tmp_path, capsys):
    from legs_jax.online import cli

    base = ["simulate", "--object", "bar_clamp", "--given-poses", "--quiet"]
    rc = cli.main([*base, "--verify", "--out", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert rc == 2 and "--verify needs --stop-at" in err and "Traceback" not in err
    rc = cli.main([*base, "--verify", "--stop-at", "1", "--out", str(tmp_path / "b")])
    assert rc == 2 and "(0, 1)" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.mark.slow  # a simulated run of its own (compiles the session's programs)
def test_a_simulated_robot_stops_where_the_test_certifies(tmp_path, capsys):
    from legs_jax.online import cli

    out = tmp_path / "run"
    args = ["simulate", "--object", "bar_clamp", "--given-poses", "--quiet"]
    args += ["--steps", "1500", "--eval-every", "50", "--stop-at", "0.6"]
    assert cli.main([*args, "--verify", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    rows = [json.loads(x) for x in (out / "curve.jsonl").read_text().splitlines()]
    last = rows[-1]
    assert last["stop"] and "certified" in printed
    state = last["verification"]
    assert state["stopped"]["step"] == last["step"] < 1500
    # the phase opened at a curve point where our bound had reached rho_min
    opened = [r for r in rows if r.get("verification") and r["step"] < last["step"]]
    assert opened and opened[0]["p_lower_ours"] >= 0.6
    # every attempt of the certifying phase is in the log, marked
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    tried = [r for r in log if r.get("type") == "tell" and r.get("verify")]
    assert len(tried) >= state["stopped"]["attempts"]
