"""The online session: recognition, alignment, sampling, bad input, persistence,
the JSON-lines protocol and the command line."""

from __future__ import annotations

import io
import json
import warnings

import numpy as np
import pytest

from legs_jax.online import InputError, Intrinsics, OrderError, Session, StateError, cli
from legs_jax.online.protocol import serve
from legs_jax.online.robot import SimRobot, World
from legs_jax.online.sampler import geometric_prior, sample_grasps

# One worker runs this file: its sessions share the compiled session programs.
pytestmark = pytest.mark.xdist_group("online-sessions")

# A 320x240 camera (half the default resolution) keeps the tests fast.
INTR = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
K = 300  # reservoir size of the sessions here


@pytest.fixture(scope="module")
def clamp() -> World:
    return World.from_mesh("bar_clamp")


def robot(world, seed=0) -> SimRobot:
    return SimRobot(world, np.random.default_rng(seed), intrinsics=INTR)


def view(rob, pose=None):
    rob.place(pose)
    return rob.render()


def given_poses(P=3, seed=0):
    rng = np.random.default_rng(seed)
    out = {}
    for s in range(P):
        a = rng.uniform(0, 2 * np.pi, K)
        out[s] = {
            "center": rng.normal(0, 0.01, (K, 3)),
            "axis": np.stack([np.cos(a), np.sin(a), np.zeros(K)], 1),
            "width": np.full(K, 0.03),
            "q": rng.uniform(0, 1, K),
            "valid": np.arange(K) < K - 10 * s,
        }
    return out


def folder_bytes(path):
    return {p.name: p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------ recognition


def test_recognition_same_pose_new_pose_and_alignment(tmp_path, clamp):
    """A second view of a pose (another place and yaw) is recognised, and the
    recognised alignment maps the pose's grasps onto the same spots of the object;
    a view of another pose is a new pose."""
    rob = robot(clamp, 1)
    with Session.create(tmp_path / "s", reservoir_size=K) as ses:
        o1 = ses.observe(view(rob, 0), INTR)
        assert o1["new"] and o1["pose"] == 0 and o1["grasps"] > 100
        T1, P1 = ses.transform.copy(), rob.placement.copy()
        o2 = ses.observe(view(rob, 0), INTR)
        assert not o2["new"] and o2["pose"] == 0 and o2["fraction"] >= 0.8
        T2, P2 = ses.transform.copy(), rob.placement.copy()
        assert not np.allclose(P1, P2)  # it did move
        c = ses.grasps[0]["center"][:100].astype(np.float64)
        # pose frame -> table (via the recognised alignment) -> object frame
        obj = []
        for T, Pl in ((T1, P1), (T2, P2)):
            tab = c @ np.linalg.inv(T)[:3, :3].T + np.linalg.inv(T)[:3, 3]
            obj.append(tab @ np.linalg.inv(Pl)[:3, :3].T + np.linalg.inv(Pl)[:3, 3])
        err = np.linalg.norm(obj[0] - obj[1], axis=1)
        assert np.median(err) < 0.003, np.median(err)
        o3 = ses.observe(view(rob, 2), INTR)
        assert o3["new"] and o3["pose"] == 1


def test_first_match_aligns_one_candidate_and_decides_as_the_full_search(clamp):
    """With every pose of bar_clamp cached, a view of a known pose is settled by
    the first candidate that matches (one alignment instead of four) and given
    the pose the full search (every candidate, best fraction) gives; a view of a
    pose not cached is compared with every candidate either way."""
    from legs_jax.online import recognition as R

    rob = SimRobot(clamp, np.random.default_rng(3))  # the 640x480 camera
    first, full = R.PoseLibrary(seed=0), R.PoseLibrary(seed=0, first_match=False)
    truth = []
    for s in range(clamp.num_poses - 1):  # the last pose stays unseen
        rob.place(s)
        pts, _ = R.object_cloud(rob.render(), rob.intrinsics, rob.camera_pose)
        _, cloud = first.recognise(pts)
        first.add(cloud)
        full.add(cloud)
        truth.append(s)
    aligned = []
    for k in range(12):
        s = k % clamp.num_poses
        rob.place(s)
        pts, _ = R.object_cloud(rob.render(), rob.intrinsics, rob.camera_pose)
        a, _ = first.recognise(pts)
        b, _ = full.recognise(pts)
        assert a.pose == b.pose  # the same decision
        if s < len(truth):
            assert a.pose is not None and truth[a.pose] == s
            aligned.append(a.candidates)
        else:  # the unseen pose: no match, every candidate compared
            assert a.pose is None and a.candidates == min(len(truth), R.CANDIDATES)
    # known poses: mostly settled by the first candidate (never more than four)
    assert np.median(aligned) == 1 and max(aligned) <= R.CANDIDATES


def test_distance_grid_reads_the_capped_distance_to_the_cloud():
    """The yaw search's grid: nearest-node and trilinear reads are within half a
    lattice diagonal of the exact capped distance (both are 1-Lipschitz), and
    points beyond the lattice read the cap."""
    from scipy.spatial import cKDTree

    from legs_jax.online import recognition as rec

    rng = np.random.default_rng(0)
    cloud = rng.uniform([-0.03, -0.02, 0.004], [0.03, 0.02, 0.04], (800, 3))
    cloud = np.concatenate([cloud, [[0.3, 0.3, 0.005]]])  # one stray reading
    tree = cKDTree(cloud)
    grid = rec.DistanceGrid(tree, cloud)
    # the stray reading does not stretch the lattice across the table
    assert np.all(grid.shape * rec.GRID < 0.06 + 2 * rec._CAP + 3 * rec.GRID)
    pts = rng.uniform([-0.05, -0.04, 0.0], [0.05, 0.04, 0.06], (5000, 3))
    exact = np.minimum(tree.query(pts)[0], rec._CAP)
    half_diag = np.sqrt(3) * rec.GRID / 2
    for read in (grid.nearest(pts), grid(pts)):
        assert np.all(np.abs(read - exact) <= half_diag + 1e-12)
        assert np.mean(np.abs(read - exact) < 0.5e-3) > 0.5
    far = np.array([[0.2, 0.0, 0.02], [0.0, -0.2, 0.02]])
    assert np.all(grid(far) == rec._CAP) and np.all(grid.nearest(far) == rec._CAP)


def test_voxel_down_is_the_mean_of_each_voxel_in_lexicographic_order():
    from legs_jax.online.recognition import voxel_down

    rng = np.random.default_rng(1)
    p = rng.uniform(-0.01, 0.01, (3000, 3))
    groups: dict = {}
    for q in p:
        groups.setdefault(tuple(np.floor(q / 0.002).astype(int)), []).append(q)
    want = np.array([np.mean(groups[k], axis=0) for k in sorted(groups)])
    np.testing.assert_allclose(voxel_down(p, 0.002), want, rtol=0, atol=1e-15)


def test_render_casts_only_near_the_object_and_gives_the_full_image(clamp):
    """Rays outside the object's box see the table: the image equals the one made
    by casting every pixel's ray."""
    rob = robot(clamp, 4)
    for pose in range(3):
        rob.place(pose)
        state = rob.rng.bit_generator.state
        fast = rob.render()
        rob.rng.bit_generator.state = state
        caster, _ = clamp.posed(rob.pose)
        tf = np.linalg.inv(rob.placement) @ rob.camera_pose
        dirs = INTR.rays().reshape(-1, 3) @ tf[:3, :3].T
        hit = caster.cast_raw(np.broadcast_to(tf[:3, 3], dirs.shape), dirs)[0]
        table = -tf[2, 3] / dirs[:, 2]
        full = np.where(hit < table, hit.astype(np.float64), table).reshape(
            INTR.height, INTR.width
        )
        full = full + rob.rng.normal(0.0, rob.noise, full.shape)
        full[rob.rng.random(full.shape) < rob.dropout] = np.nan
        np.testing.assert_array_equal(fast, full)
        assert np.sum(fast < 0.69) > 500  # the object is in view


def test_sampled_grasps_of_a_box_are_antipodal_and_mostly_succeed(box):
    rob = robot(box, 3)
    d = view(rob, 0)
    g = sample_grasps(d, INTR, rob.camera_pose, 200, np.random.default_rng(0))
    assert len(g) == 200
    # contacts on opposite faces: the width is about one of the box's sides (40 or
    # 60 mm; the edge pixels lie up to two pixels, 5 mm, inside the rim; the axis
    # may lean up to 45° off the face normals; a few pinch a corner)
    assert np.mean((g.width > 0.03) & (g.width < 0.08)) > 0.95
    assert np.mean(np.abs(g.width - 0.04) < 0.01) > 0.3
    assert np.allclose(g.axis[:, 2], 0) and np.allclose(
        np.linalg.norm(g.axis, axis=1), 1
    )
    q = geometric_prior(g)
    assert np.all((q >= 0.3) & (q <= 0.7))
    # executed with the physics (20 perturbed executions each): many hold, and the
    # stand-in prior (which reads only the image) ranks them: the grasps it scores
    # in the top half succeed far more often than the bottom half
    p = np.array(
        [
            rob.success(*rob.to_pose_frame(c, a), samples=20)
            for c, a in zip(g.center[:100], g.axis[:100], strict=True)
        ]
    )
    assert p.mean() > 0.3, p.mean()
    top = q[:100] >= np.median(q[:100])
    assert p[top].mean() > p[~top].mean() + 0.2, (p[top].mean(), p[~top].mean())


# ------------------------------------------------------------------ bad input


def test_bad_input_gets_a_clear_error_and_changes_nothing(tmp_path, clamp):
    rob = robot(clamp, 2)
    folder = tmp_path / "s"
    with Session.create(folder, reservoir_size=K) as ses:
        with pytest.raises(OrderError, match="observe"):
            ses.ask()
        good = view(rob, 0)
        table = np.full((INTR.height, INTR.width), 0.7)
        cases = [
            (good[:100], INTR, "intrinsics say"),
            (np.full_like(good, np.nan), INTR, "empty"),
            (np.zeros_like(good), INTR, "empty"),
            (table, INTR, "no object in view"),
            (good * 1000, INTR, "metres"),
            (good, {"fx": 1}, "intrinsics lack"),
            (good, {**INTR.to_dict(), "fx": -5}, "fx, fy > 0"),
            (np.stack([good, good]), INTR, "2-D"),
            ("not an image", INTR, "2-D|numbers"),
        ]
        before = folder_bytes(folder)
        for depth, intr, msg in cases:
            with pytest.raises(InputError, match=msg):
                ses.observe(depth, intr)
        assert folder_bytes(folder) == before
        ses.observe(good, INTR)
        with pytest.raises(OrderError, match="without a pending ask"):
            ses.tell(True)
        ses.ask()
        before = folder_bytes(folder)
        for bad in ("yes", 1, None):
            with pytest.raises(InputError, match="true or false"):
                ses.tell(bad)
        with pytest.raises(InputError, match="rho_min"):
            ses.bound(1.5)
        assert folder_bytes(folder) == before
        ses.tell(True)
        with pytest.raises(OrderError):
            ses.tell(True)  # the outcome of one ask is told once


def test_ask_is_idempotent_and_counts_follow_the_engine(tmp_path):
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        ses.observe(pose=0)  # first landing: counted
        a = ses.ask()
        assert ses.ask() == a
        ses.tell(False)
        ses.observe(pose=1)  # a topple: observed, not counted
        ses.ask()
        ses.tell(True)
        ses.observe(pose=2)  # a drop after a success: counted
        ses.observe(pose=1)  # looked again before grasping: the count moves
        assert ses.counts[:3].tolist() == [1, 1, 0]
        assert ses.observed[:3].all()
        b = ses.bound(0.0)
        assert b["stop"] and 0 <= b["p_lower_attempted"] <= b["p_lower"] <= 1
        assert b["stop_ours"] and 0 <= b["p_lower_ours"] <= 1


@pytest.mark.parametrize("ok", [True, False])
def test_our_bound_follows_the_outcomes(tmp_path, ok):
    # One pose, every landing counted after a success: λ' is nearly all on it, so
    # our bound is about the lower tail of the recommended grasp's posterior.
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        for _ in range(150):
            ses.observe(pose=0)
            ses.ask()
            ses.tell(ok)
        b = ses.bound(0.8)
    if ok:
        assert b["p_lower_ours"] > 0.8 and b["stop_ours"]
    else:
        assert b["p_lower_ours"] < 0.2 and not b["stop_ours"]


@pytest.mark.slow  # compiles a second set of the session's programs (~20 s)
def test_the_bootstrapped_bound_is_kept_by_the_session_and_replayed(tmp_path):
    """A session created with ``bound_replicates`` computes our bound from the
    bootstrapped fit: it differs from a plug-in session's on the same outcomes,
    and a resumed session gives it again bit for bit."""
    rng = np.random.default_rng(3)
    script = [(int(rng.integers(3)), bool(rng.random() < 0.6)) for _ in range(60)]
    got = {}
    for name, r in (("plug", 0), ("boot", 8)):
        with Session.create(
            tmp_path / name, given_poses=given_poses(), bound_replicates=r
        ) as ses:
            for pose, ok in script:
                ses.observe(pose=pose)
                ses.ask()
                ses.tell(ok)
            got[name] = ses.bound(0.5)["p_lower_ours"]
    assert got["plug"] != got["boot"]
    with Session.open(tmp_path / "boot") as ses:
        assert ses.loop.bound_ours(ses.counts, ses.observed, ses.step) == got["boot"]
    with pytest.raises(InputError, match="bound_replicates"):
        Session.create(tmp_path / "bad", given_poses=given_poses(), bound_replicates=-1)


def test_simulate_refuses_a_bad_stopping_threshold():
    from legs_jax.online.simulate import _check_stop_at

    for bad in (1.5, -0.1, "0.8", True):
        with pytest.raises(InputError, match="stopping threshold"):
            _check_stop_at(bad)
    _check_stop_at(None)
    _check_stop_at(0.8)


# ------------------------------------------------------------------ persistence


def _script(steps, seed, P=3):
    """(pose, outcome) of each step."""
    rng = np.random.default_rng(seed)
    return [(int(rng.integers(P)), bool(rng.random() < 0.4)) for _ in range(steps)]


def _drive(ses, script):
    for pose, ok in script:
        ses.observe(pose=pose)
        ses.ask()
        ses.tell(ok)


def test_resume_replays_every_outcome_exactly(tmp_path):
    """A session closed and reopened halfway makes the same choices as one run
    straight through, and holds the same posteriors and counts."""
    script = _script(120, 0)
    with Session.create(tmp_path / "a", given_poses=given_poses(), seed=3) as a:
        _drive(a, script)
        rec_a, est_a, counts_a = a.loop.recommendation(), a.loop.estimates(), a.counts
        log_a = (tmp_path / "a" / "log.jsonl").read_text()
    with Session.create(tmp_path / "b", given_poses=given_poses(), seed=3) as b:
        _drive(b, script[:50])
    with Session.open(tmp_path / "b") as b:
        assert b.step == 50
        _drive(b, script[50:])
        assert np.array_equal(b.loop.recommendation(), rec_a)
        assert np.array_equal(b.counts, counts_a)
        for x, y in zip(b.loop.estimates(), est_a, strict=True):
            np.testing.assert_array_equal(x, y)
    assert (tmp_path / "b" / "log.jsonl").read_text() == log_a


def test_corrupt_foreign_and_torn_state_files(tmp_path):
    folder = tmp_path / "s"
    with Session.create(folder, given_poses=given_poses()) as ses:
        _drive(ses, _script(10, 1))
        with pytest.raises(StateError, match="another process"):
            Session.open(folder)
    with pytest.raises(StateError, match="already holds a session"):
        Session.create(folder, given_poses=given_poses())
    log = folder / "log.jsonl"
    good = log.read_bytes()
    lines = good.split(b"\n")
    # a torn last record (a kill during the write): dropped, the rest resumes
    log.write_bytes(good + lines[-2][:25])
    with pytest.warns(UserWarning, match="torn"):
        with Session.open(folder) as ses:
            assert ses.step == 10
    assert log.read_bytes() == good
    # a damaged record inside the log
    bad = lines.copy()
    bad[5] = bad[5][:-3] + b"}}}"
    log.write_bytes(b"\n".join(bad))
    with pytest.raises(StateError, match="line 6"):
        Session.open(folder)
    log.write_bytes(good)
    # an altered pose file
    pose = folder / "poses" / "001.npz"
    pose_bytes = pose.read_bytes()
    pose.write_bytes(pose_bytes[:-1] + bytes([pose_bytes[-1] ^ 1]))
    with pytest.raises(StateError, match="checksum"):
        Session.open(folder)
    pose.write_bytes(pose_bytes)
    # foreign or missing session files
    cfg = folder / "session.json"
    text = cfg.read_text()
    cfg.write_text(json.dumps({"format": "something else"}))
    with pytest.raises(StateError, match="not a legs_jax online session"):
        Session.open(folder)
    cfg.write_text("{not json")
    with pytest.raises(StateError, match="not a session file"):
        Session.open(folder)
    cfg.write_text(text)
    with pytest.raises(StateError, match="holds no session"):
        Session.open(tmp_path / "elsewhere")
    with Session.open(folder) as ses:
        assert ses.step == 10


def test_a_tampered_outcome_is_refused(tmp_path):
    folder = tmp_path / "s"
    with Session.create(folder, given_poses=given_poses()) as ses:
        _drive(ses, _script(5, 2))
    log = folder / "log.jsonl"
    text = log.read_text()
    flipped = text.replace('"success":true', '"success":false', 1)
    if flipped == text:
        flipped = text.replace('"success":false', '"success":true', 1)
    log.write_text(flipped)
    with pytest.raises(StateError, match="corrupt"):
        Session.open(folder)


# ------------------------------------------------------------------ protocol


def test_json_lines_exchange(tmp_path, clamp):
    rob = robot(clamp, 4)
    np.save(tmp_path / "frame.npy", view(rob, 0))
    intr = INTR.to_dict()
    reqs = [
        {"id": 1, "cmd": "ask"},
        {
            "id": 2,
            "cmd": "observe",
            "depth": {"npy": str(tmp_path / "frame.npy")},
            "intrinsics": intr,
        },
        {"id": 3, "cmd": "ask"},
        {"id": 4, "cmd": "tell", "success": True},
        {"id": 5, "cmd": "tell", "success": True},
        {"id": 6, "cmd": "bound", "rho_min": 0.9},
        {
            "id": 7,
            "cmd": "observe",
            "depth": {"b64": "AAAA", "dtype": "float32", "shape": [2, 2]},
            "intrinsics": intr,
        },
        {"id": 8, "cmd": "dance"},
        {"id": 9, "cmd": "status"},
        {"id": 10, "cmd": "quit"},
    ]
    stdin = io.StringIO("\n".join(json.dumps(r) for r in reqs) + "\nnot json\n")
    stdout = io.StringIO()
    with Session.create(tmp_path / "s", reservoir_size=K) as ses:
        serve(ses, stdin, stdout)
    out = [json.loads(line) for line in stdout.getvalue().splitlines()]
    assert out[0]["ok"] and "ready" in out[0]
    by_id = {r["id"]: r for r in out[1:]}
    assert [r["id"] for r in out[1:]] == list(range(1, 11))  # stops at quit
    assert not by_id[1]["ok"] and by_id[1]["error"]["type"] == "OrderError"
    assert by_id[2]["ok"] and by_id[2]["result"]["new"]
    g = by_id[3]["result"]
    assert len(g["center_table"]) == 3 and 0 < g["width"] <= 0.08
    assert g["depth"] == pytest.approx(0.7 - g["height"], abs=1e-9)
    assert by_id[4]["ok"] and by_id[4]["result"]["step"] == 1
    assert by_id[5]["error"]["type"] == "OrderError"
    assert by_id[6]["ok"] and set(by_id[6]["result"]) >= {"p_lower", "stop"}
    assert "bytes" in by_id[7]["error"]["message"]
    assert "unknown cmd" in by_id[8]["error"]["message"]
    assert by_id[9]["result"]["step"] == 1


# ------------------------------------------------------------------ command line


def test_cli_help_and_clear_errors(tmp_path, capsys, monkeypatch):
    """Refusals print one line and exit 2; a refused ``simulate`` turns JAX's
    compilation cache on nowhere (it is process-wide)."""
    turned_on = []
    monkeypatch.setattr(cli, "compile_cache", turned_on.append)
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0
    assert "JSON" in capsys.readouterr().out
    for cmd in ("serve", "simulate", "recognition-table", "bench"):
        with pytest.raises(SystemExit):
            cli.main([cmd, "--help"])
        assert "usage" in capsys.readouterr().out
    assert (
        cli.main(
            ["simulate", "--object", "no_such_thing", "--out", str(tmp_path / "x")]
        )
        == 2
    )
    assert "no_such_thing" in capsys.readouterr().err
    assert (
        cli.main(
            [
                "simulate",
                "--object",
                "bar_clamp",
                "--steps",
                "0",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 2
    )
    assert "--steps" in capsys.readouterr().err
    (tmp_path / "y").mkdir()
    (tmp_path / "y" / "session.json").write_text("{}")
    assert (
        cli.main(["simulate", "--object", "bar_clamp", "--out", str(tmp_path / "y")])
        == 2
    )
    assert "--resume" in capsys.readouterr().err
    assert turned_on == []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert (
            cli.main(
                [
                    "simulate",
                    "--object",
                    "bar_clamp",
                    "--out",
                    str(tmp_path / "y"),
                    "--resume",
                ]
            )
            == 2
        )
    assert "not a legs_jax online session" in capsys.readouterr().err


def test_resume_refuses_a_run_of_another_kind(tmp_path, capsys):
    """--resume on a session that is not a simulated run, or of another object."""
    with Session.create(tmp_path / "s", given_poses=given_poses()):
        pass
    args = ["simulate", "--object", "bar_clamp", "--out", str(tmp_path / "s")]
    assert cli.main([*args, "--resume"]) == 2
    assert "not a simulated run" in capsys.readouterr().err


def test_protocol_refuses_unknown_fields_and_a_foreign_grasp(tmp_path):
    """A field the command does not take, or a tell that names
    another grasp than the pending one, is refused with a JSON error line and
    records nothing; the session goes on."""
    reqs = [
        {"id": 1, "cmd": "observe", "pose": 0},
        {"id": 2, "cmd": "ask"},
        {"id": 3, "cmd": "tell", "grasp": 99999, "success": False},
        {"id": 4, "cmd": "tell", "success": False, "sucess": True},
        {"id": 5, "cmd": "ask", "pose": 2},
        {"id": 6, "cmd": "status", "verbose": True},
        {"id": 7, "cmd": "tell", "grasp": True, "success": True},
        {"id": 8, "cmd": "status"},
    ]
    stdin = io.StringIO("\n".join(json.dumps(r) for r in reqs) + "\n")
    stdout = io.StringIO()
    with Session.create(tmp_path / "s", given_poses=given_poses()) as ses:
        serve(ses, stdin, stdout)
        grasp = ses.pending_grasp()
        tells = [r for r in ses.store.records if r["type"] == "tell"]
    out = {r["id"]: r for r in map(json.loads, stdout.getvalue().splitlines()[1:])}
    assert out[1]["ok"] and out[2]["ok"] and grasp == out[2]["result"]["grasp"]
    assert grasp != 99999 and not tells and out[8]["result"]["step"] == 0
    assert out[3]["error"]["type"] == "OrderError"
    assert "grasp 99999" in out[3]["error"]["message"]
    assert f"pending grasp is {grasp}" in out[3]["error"]["message"]
    for i, field in [(4, "'sucess'"), (5, "'pose'"), (6, "'verbose'")]:
        assert not out[i]["ok"] and out[i]["error"]["type"] == "InputError"
        assert f"unknown field(s) {field}" in out[i]["error"]["message"]
    assert not out[7]["ok"]  # true is not a grasp id
    # the pending grasp named right is recorded
    stdin = io.StringIO(
        json.dumps({"id": 9, "cmd": "tell", "grasp": grasp, "success": True}) + "\n"
    )
    stdout = io.StringIO()
    with Session.open(tmp_path / "s") as ses:
        ses.observe(pose=0)
        assert ses.ask()["grasp"] == grasp  # the same draw after a restart
        serve(ses, stdin, stdout)
        assert ses.step == 1 and ses.successes == 1
    assert json.loads(stdout.getvalue().splitlines()[1])["ok"]


def test_a_second_serve_is_refused_as_a_json_line(tmp_path):
    """A second serve on a held session answers in JSON (the robot
    program reads JSON lines) and exits with status 2."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root))
    with Session.create(tmp_path / "s", given_poses=given_poses()):
        r = subprocess.run(
            [sys.executable, "-m", "legs_jax.online", "serve", str(tmp_path / "s")],
            input="", capture_output=True, text=True, env=env, timeout=300,
        )  # fmt: skip
    assert r.returncode == 2
    (line,) = r.stdout.splitlines()
    msg = json.loads(line)
    assert msg["ok"] is False and msg["error"]["type"] == "StateError"
    assert "Traceback" not in r.stderr


def test_recognition_table_regenerate_line_names_the_objects():
    """The table's "Regenerate" command gives back the same table:
    it names --objects when they are not the default 13."""
    from legs_jax.online.recognition_table import DEXNET_OBJECTS, table_markdown

    row = {"object": "pawn", "poses": 10, "views": 5, "right": 5, "new": 3}
    row |= {"duplicates": 0, "wrong_merges": 0, "cached": 3, "median_s": 0.1}
    text = table_markdown([row], 5, 3, ["pawn", "vase"])
    assert "recognition-table --views 5 --seed 3 --objects pawn vase`" in text
    text = table_markdown([row], 5, 3, list(DEXNET_OBJECTS))
    assert "recognition-table --views 5 --seed 3`" in text


_FAKE_SERVE = (
    "import sys\n"
    "print('{\"ok\": true}', flush=True)\n"
    "for i, line in enumerate(sys.stdin):\n"
    "    if i == int(sys.argv[1]):\n"
    "        sys.exit(3)\n"
    "    print('{\"ok\": true}', flush=True)\n"
)


@pytest.mark.parametrize("dies_at", [99, 1])
def test_online_bench_exchange_reports_a_serve_that_died(dies_at):
    """online bench's timing of a serve's first requests: a full exchange gives a
    time for each request; a serve that ends mid-exchange is a one-line error that
    names the request, and the process is not left behind."""
    import subprocess
    import sys

    from legs_jax.online import bench

    reqs = [{"cmd": "observe"}, {"cmd": "ask"}, {"cmd": "tell"}]
    with subprocess.Popen(
        [sys.executable, "-c", _FAKE_SERVE, str(dies_at)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    ) as proc:
        if dies_at == 99:
            times = bench._exchange(proc, reqs)
            assert list(times) == ["open", "observe", "ask", "tell"]
            assert all(t >= 0 for t in times.values())
        else:
            with pytest.raises(
                RuntimeError, match="before it answered ask .exit code 3"
            ):
                bench._exchange(proc, reqs)
    assert proc.returncode in (0, 3)
