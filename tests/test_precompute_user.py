"""precompute with a user's own meshes and a user's own work: meshes of several
pieces, URDF assets, --scale, problems that cannot be learned, where the problem
file says its mesh is, and no command replacing a committed file unless told."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from legs_jax.core import problem as problem_mod
from precompute.build import BuildParams, build_problem
from precompute.cli import main
from precompute.errors import PrecomputeError
from precompute.mesh import TOUCH, load_mesh

REPO = Path(__file__).resolve().parent.parent
SHIPPED_WEIGHTS = REPO / "precompute" / "prior_weights" / "weights.npz"
SUMMARY = REPO / "results" / "precompute" / "summary.csv"
SMALL = ["--trials", "2", "--grasps", "60", "--samples", "4", "--jobs", "1"]


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _box(extents, at=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents)
    m.apply_translation(at)
    return m


def _save(folder: Path, name: str, mesh) -> Path:
    path = folder / name
    mesh.export(path)
    return path


# ------------------------------------------------------- meshes of several pieces


def test_two_touching_boxes_are_one_rigid_body(tmp_path):
    # face to face, the upper box shifted so that no vertex of one lies on a
    # vertex of the other: only their faces touch
    a = _box((0.06, 0.04, 0.02), (0.0, 0.0, 0.01))
    b = _box((0.03, 0.02, 0.02), (0.01, 0.005, 0.03))
    path = _save(tmp_path, "touching.obj", trimesh.util.concatenate([a, b]))
    m = load_mesh(path, "m")
    solid = m.trimesh()
    assert solid.is_watertight
    assert solid.volume == pytest.approx(a.volume + b.volume, rel=1e-6)
    assert np.ptp(m.vertices, axis=0) == pytest.approx([0.06, 0.04, 0.04], abs=1e-7)
    # the centre of mass of the whole, not of one piece
    want = (a.volume * a.center_mass + b.volume * b.center_mass) / (a.volume + b.volume)
    assert m.center_mass == pytest.approx(want, abs=1e-6)
    assert any("joined 2" in r for r in m.repairs)


def test_two_overlapping_boxes_are_their_union(tmp_path):
    a = _box((0.06, 0.04, 0.03))
    b = _box((0.06, 0.04, 0.03), (0.03, 0.0, 0.0))  # half inside a
    path = _save(tmp_path, "overlap.obj", trimesh.util.concatenate([a, b]))
    m = load_mesh(path, "m")
    assert m.trimesh().volume == pytest.approx(0.09 * 0.04 * 0.03, rel=1e-6)
    assert len(m.trimesh().split(only_watertight=False)) == 1


def test_boxes_far_apart_are_refused_naming_file_gap_and_next_step(tmp_path):
    a = _box((0.04, 0.04, 0.04))
    b = _box((0.04, 0.04, 0.04), (0.1, 0.0, 0.0))  # a 60 mm gap
    path = _save(tmp_path, "apart.obj", trimesh.util.concatenate([a, b]))
    with pytest.raises(PrecomputeError) as info:
        load_mesh(path, "m")
    msg = str(info.value)
    assert str(path) in msg and "2 separate bodies" in msg
    assert "60 mm apart" in msg and "its own file" in msg and "\n" not in msg


def test_a_gap_within_the_stated_tolerance_is_a_touch(tmp_path):
    a = _box((0.05, 0.05, 0.05))
    diag = np.linalg.norm([0.05, 0.05, 0.1 + 0.0])
    gap = 0.4 * TOUCH * diag  # well inside the tolerance
    b = _box((0.05, 0.05, 0.05), (0.0, 0.0, 0.05 + gap))
    path = _save(tmp_path, "gap.obj", trimesh.util.concatenate([a, b]))
    m = load_mesh(path, "m")
    assert m.trimesh().volume == pytest.approx(2 * 0.05**3, rel=1e-6)
    assert any("touch" in r for r in m.repairs)
    # ten times the tolerance: apart
    b = _box((0.05, 0.05, 0.05), (0.0, 0.0, 0.05 + 10 * TOUCH * diag))
    path = _save(tmp_path, "gap2.obj", trimesh.util.concatenate([a, b]))
    with pytest.raises(PrecomputeError, match="separate bodies"):
        load_mesh(path, "m")


def _shared_edge_pieces(folder: Path) -> tuple[Path, float]:
    """An .obj of two closed cubes that share one edge (the same vertex indices
    within each piece, the edge's points written twice): each piece watertight,
    merged at the shared points they are not."""
    a = _box((0.04, 0.04, 0.04), (0.02, 0.02, 0.02))
    b = _box((0.04, 0.04, 0.04), (0.06, 0.02, 0.06))  # shares the edge x=.04,z=.04
    lines = []
    for v in np.vstack([a.vertices, b.vertices]):
        lines.append(f"v {v[0]:.9f} {v[1]:.9f} {v[2]:.9f}")
    for off, m in ((1, a), (1 + len(a.vertices), b)):
        lines += [f"f {f[0] + off} {f[1] + off} {f[2] + off}" for f in m.faces]
    path = folder / "edge.obj"
    path.write_text("\n".join(lines) + "\n")
    return path, a.volume + b.volume


def test_a_mesh_of_watertight_pieces_is_not_refused_for_holes(tmp_path):
    path, volume = _shared_edge_pieces(tmp_path)
    merged = trimesh.load(path, force="mesh", process=False)
    merged.merge_vertices()
    assert not merged.is_watertight  # what the pieces are when glued at the edge
    m = load_mesh(path, "m")
    assert m.trimesh().is_watertight
    assert m.trimesh().volume == pytest.approx(volume, rel=1e-6)


# ---------------------------------------------------------------- --scale, URDF


def test_scale_applies_after_units_and_is_recorded(tmp_path, capsys):
    path = _save(tmp_path, "box.obj", _box((40.0, 60.0, 30.0)))  # millimetres
    m = load_mesh(path, "mm", scale=0.5)
    assert np.ptp(m.vertices, axis=0) == pytest.approx([0.02, 0.03, 0.015])
    out = tmp_path / "p"
    args = ["--mesh", str(path), "--units", "mm", "--scale", "0.5", "--out", str(out)]
    assert main([*args, *SMALL, "--prior", "synthetic", "--quiet"]) == 0
    meta = problem_mod.peek(out / "custom" / "box.npz")["meta"]
    assert meta["scale"] == 0.5 and meta["mesh_scale"] == pytest.approx(0.0005)
    # the mesh is recorded as read at that scale: read without it, it is another
    assert meta["mesh_sha256"] == m.sha256 != load_mesh(path, "mm").sha256
    assert load_mesh(path, "mm").sha256 == _sha(path)
    # the same command again: up to date
    capsys.readouterr()
    assert main([*args, *SMALL, "--prior", "synthetic", "--quiet"]) == 0
    assert "1 up-to-date problem file(s) skipped" in capsys.readouterr().out
    # another scale is another problem: not up to date
    capsys.readouterr()
    assert main([*args[:-4], "--scale", "0.6", "--out", str(out), *SMALL,
                 "--prior", "synthetic", "--quiet"]) == 0  # fmt: skip
    assert "skipped" not in capsys.readouterr().out
    assert main(["--mesh", str(path), "--units", "mm", "--scale", "-1"]) == 2
    assert "--scale must be a positive number" in capsys.readouterr().err


def _urdf(folder: Path, mesh_name: str, scale: str, collision: bool = True) -> Path:
    geo = f'<geometry><mesh filename="{mesh_name}" scale="{scale}"/></geometry>'
    other = '<geometry><box size="0.5 0.5 0.5"/></geometry>'
    text = (
        '<?xml version="1.0"?>\n<robot name="thing"><link name="base">'
        f"<visual>{other if collision else geo}</visual>"
        + (f"<collision><origin xyz='0.1 0 0'/>{geo}</collision>" if collision else "")
        + "</link></robot>\n"
    )
    path = folder / "thing.urdf"
    path.write_text(text)
    return path


def test_urdf_collision_mesh_at_its_scale(tmp_path):
    (tmp_path / "meshes").mkdir()
    _save(tmp_path / "meshes", "part.obj", _box((4.0, 6.0, 2.0)))
    path = _urdf(tmp_path, "meshes/part.obj", "0.015 0.015 0.015")
    m = load_mesh(path)  # a URDF's lengths are metres
    assert np.ptp(m.vertices, axis=0) == pytest.approx([0.06, 0.09, 0.03])
    # package:// is looked for beside the URDF
    path = _urdf(tmp_path, "package://thing/meshes/part.obj", "0.01 0.01 0.01")
    assert np.ptp(load_mesh(path).vertices, axis=0) == pytest.approx([0.04, 0.06, 0.02])
    # no collision geometry: the visual mesh
    path = _urdf(tmp_path, "meshes/part.obj", "0.01", collision=False)
    assert np.ptp(load_mesh(path).vertices, axis=0) == pytest.approx([0.04, 0.06, 0.02])
    # --scale after the URDF's scale
    path = _urdf(tmp_path, "meshes/part.obj", "0.01 0.01 0.01")
    m = load_mesh(path, "m", scale=2.0)
    assert np.ptp(m.vertices, axis=0) == pytest.approx([0.08, 0.12, 0.04])


def test_urdf_build_records_where_its_mesh_is(tmp_path, capsys):
    (tmp_path / "assets" / "meshes").mkdir(parents=True)
    _save(tmp_path / "assets" / "meshes", "part.obj", _box((4.0, 6.0, 3.0)))
    urdf = _urdf(tmp_path / "assets", "meshes/part.obj", "0.01 0.01 0.01")
    out = tmp_path / "elsewhere"
    code = main(["--mesh", str(urdf), "--out", str(out), *SMALL, "--quiet",
                 "--prior", "synthetic"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    dest = out / "custom" / "thing.npz"
    meta = problem_mod.peek(dest)["meta"]
    assert (dest.parent / meta["mesh_file"]).resolve() == urdf.resolve()
    assert Path(meta["mesh_file_abs"]) == urdf.resolve()
    assert meta["units"] == "m"
    assert meta["urdf"][0]["scale"] == [0.01, 0.01, 0.01]
    assert meta["urdf"][0]["source"] == "collision"
    # changing the mesh the URDF names makes the problem out of date
    capsys.readouterr()
    _save(tmp_path / "assets" / "meshes", "part.obj", _box((4.0, 6.0, 3.5)))
    assert main(["--mesh", str(urdf), "--out", str(out), *SMALL, "--quiet",
                 "--prior", "synthetic"]) == 0  # fmt: skip
    assert "skipped" not in capsys.readouterr().out


def test_urdf_refusals_name_file_defect_and_next_step(tmp_path):
    _save(tmp_path, "big.obj", _box((4.0, 6.0, 2.0)))
    path = _urdf(tmp_path, "big.obj", "0.5 0.5 0.5")  # 3 m long
    with pytest.raises(PrecomputeError, match=r"implausible size.*--scale 0\.033"):
        load_mesh(path)
    path = _urdf(tmp_path, "missing.obj", "1 1 1")
    with pytest.raises(PrecomputeError) as info:
        load_mesh(path)
    msg = str(info.value)
    assert str(path) in msg and "missing.obj" in msg and "not found" in msg
    two = tmp_path / "arm.urdf"
    link = '<link name="{}"><visual><geometry><box size="0.05 0.05 0.05"/></geometry></visual></link>'  # noqa: E501
    two.write_text(f"<robot name='arm'>{link.format('a')}{link.format('b')}</robot>")
    with pytest.raises(PrecomputeError, match="2 links with geometry.*one part"):
        load_mesh(two)
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link")
    with pytest.raises(PrecomputeError, match="bad.urdf: not a URDF"):
        load_mesh(bad)


@pytest.mark.parametrize(
    ("name", "words"),
    [
        ("problem.npz", ["problem file", "simulate --object"]),
        ("model.dae", ["export it as .obj", "--mesh"]),
        ("scene.sdf", ["not supported", "URDF"]),
        ("notes.txt", ["not a mesh file", ".urdf"]),
    ],
)
def test_a_file_of_the_wrong_kind_names_what_to_do(tmp_path, capsys, name, words):
    path = tmp_path / name
    path.write_bytes(b"something")
    assert main(["--mesh", str(path)]) == 2  # before asking for --units
    err = capsys.readouterr().err
    assert str(path) in err and "Traceback" not in err and err.count("\n") == 1
    for w in words:
        assert w in err


# ------------------------------------------------------- problems not learnable


def test_a_pose_without_any_grasp_is_flagged_recorded_and_reported(
    tmp_path, capsys, monkeypatch
):
    # a plate 150 mm square lying flat: wider than the 80 mm opening, and a pose
    # that does not topple: no grasp can succeed and a rollout stays there
    path = _save(tmp_path, "plate.obj", _box((0.15, 0.15, 0.012)))
    out = tmp_path / "problems"
    args = ["--mesh", str(path), "--units", "m", "--out", str(out), *SMALL]
    assert main([*args, "--prior", "synthetic", "--quiet"]) == 0
    stdout = capsys.readouterr().out
    pb = problem_mod.load(out / "custom" / "plate.npz")
    flat = int(np.argmax(pb.landing))  # lying flat is the likeliest pose
    assert pb.valid[:, flat].sum() == 0
    flags = {f["pose"]: f for f in pb.meta["unlearnable"]}
    assert flat in flags
    assert flags[flat]["trials_without_success"] == pb.num_trials
    assert flags[flat]["cannot_leave"]
    warn = [ln for ln in stdout.splitlines() if ln.startswith("warning: plate: ")]
    assert any(f"pose {flat} " in ln and "stuck" in ln for ln in warn)
    assert len(warn) == len(flags)
    # the report lists it, in its own folder
    monkeypatch.chdir(tmp_path)
    code = main(["report", "--problems", str(out), "--no-figures", "--quiet"])
    assert code == 0
    report_out = tmp_path / "runs" / "precompute-report"
    import csv

    with open(report_out / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["object"] for r in rows] == ["plate"]
    assert str(flat) in rows[0]["unlearnable_poses"].split(";")
    assert "plate" in (report_out / "unlearnable.md").read_text()
    assert "cannot be learned" in capsys.readouterr().out


def test_the_problem_file_tells_later_commands_where_its_mesh_is(tmp_path):
    from legs_jax.online.robot import World

    (tmp_path / "meshes").mkdir()
    mesh = _save(tmp_path / "meshes", "brick.obj", _box((0.05, 0.03, 0.02)))
    dest = tmp_path / "out" / "custom" / "brick.npz"
    params = BuildParams(trials=1, grasps=40, samples=4, prior="synthetic")
    pb = build_problem(mesh, units="m", name="brick", params=params, problem_file=dest)
    problem_mod.save(pb, dest)
    loaded = problem_mod.load(dest)
    assert (dest.parent / loaded.meta["mesh_file"]).resolve() == mesh.resolve()
    world = World.from_problem(loaded, problem_path=dest)
    assert np.ptp(world.vertices, axis=0).max() == pytest.approx(0.05)
    # moved alone, far away: found by its absolute path
    alone = tmp_path / "x" / "y" / "z" / "brick.npz"
    alone.parent.mkdir(parents=True)
    shutil.copy(dest, alone)
    world = World.from_problem(problem_mod.load(alone), problem_path=alone)
    assert np.ptp(world.vertices, axis=0).max() == pytest.approx(0.05)
    # moved together with its mesh (the same layout elsewhere): found beside it
    moved = tmp_path / "copy"
    shutil.copytree(tmp_path / "meshes", moved / "meshes")
    shutil.copytree(tmp_path / "out", moved / "out")
    shutil.rmtree(tmp_path / "meshes")
    pb2 = problem_mod.load(moved / "out" / "custom" / "brick.npz")
    world = World.from_problem(pb2, problem_path=moved / "out" / "custom" / "brick.npz")
    assert np.ptp(world.vertices, axis=0).max() == pytest.approx(0.05)


# ------------------------------------------------- committed files stay as they are


def test_report_of_part_of_the_catalogue_never_cuts_the_committed_summary(
    tmp_path, monkeypatch, capsys
):
    from legs_jax import synthetic

    before = _sha(SUMMARY)
    probs = tmp_path / "problems"
    for name in ("bar_clamp", "pawn"):
        pb = synthetic.make_problem(seed=1, num_poses=2, num_grasps=50, name=name)
        problem_mod.save(pb, probs / "dexnet_adv" / f"{name}.npz")
    monkeypatch.chdir(REPO)
    code = main(["report", "--problems", str(probs), "--no-figures", "--quiet",
                 "--out", str(tmp_path / "r")])  # fmt: skip
    assert code == 0
    assert "report of 2 object(s) -> " in capsys.readouterr().out
    code = main(["report", "--problems", str(probs), "--no-figures", "--quiet",
                 "--out", "results/precompute"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and "committed" in err
    monkeypatch.chdir(tmp_path)
    assert main(["report", "--problems", str(probs), "--no-figures", "--quiet"]) == 0
    assert (tmp_path / "runs" / "precompute-report" / "summary.csv").is_file()
    assert not (tmp_path / "results").exists()
    assert _sha(SUMMARY) == before


def test_build_over_the_committed_set_needs_overwrite(capsys):
    shipped = REPO / "data" / "problemset"
    target = shipped / "dexnet_adv" / "pawn.npz"
    before = _sha(target)
    assert main(["--object", "pawn", "--out", str(shipped), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and "committed" in err
    assert _sha(target) == before


def test_ship_into_the_committed_set_needs_overwrite(capsys):
    assert main(["ship", "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_train_prior_into_the_shipped_weights_needs_overwrite(tmp_path, capsys):
    before = _sha(SHIPPED_WEIGHTS)
    assert main(["train-prior", "--quick", "--out", str(SHIPPED_WEIGHTS.parent)]) == 2
    err = capsys.readouterr().err
    assert "shipped weights" in err and "--overwrite" in err
    assert _sha(SHIPPED_WEIGHTS) == before


def test_train_prior_without_flags_goes_to_runs_prior(tmp_path, monkeypatch, capsys):
    """Where a run writes, the training itself replaced by a stand-in that writes
    a weights file where it is told (the real run: the slow test below)."""
    from precompute import train_prior

    told = []

    def fake_run(cfg, out, jobs, progress=True):
        told.append(Path(out))
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "weights.npz").write_bytes(b"new")
        m = {"accuracy": 0.5, "roc_auc": 0.5, "loss": 0.7}
        return {
            "metrics": {"test": m},
            "history": {"val_loss_init": 0.7, "val_loss_best": 0.6},
            "timings_s": {"total": 1.0},
        }

    monkeypatch.setattr(train_prior, "run", fake_run)
    monkeypatch.chdir(tmp_path)
    before = _sha(SHIPPED_WEIGHTS)
    assert main(["train-prior", "--quick", "--quiet"]) == 0
    assert told == [tmp_path / "runs" / "prior"]
    assert str(tmp_path / "runs" / "prior") in capsys.readouterr().out
    assert main(["train-prior", "--quick", "--out", str(tmp_path / "mine")]) == 0
    assert told[-1] == tmp_path / "mine"
    assert _sha(SHIPPED_WEIGHTS) == before


@pytest.mark.slow
def test_train_prior_without_flags_writes_runs_prior(tmp_path, monkeypatch, capsys):
    before = _sha(SHIPPED_WEIGHTS)
    monkeypatch.chdir(tmp_path)
    tiny = ["--objects", "20", "--grasps", "20", "--poses", "1", "--samples", "3",
            "--epochs", "1", "--batch", "16", "--jobs", "1", "--quiet"]  # fmt: skip
    assert main(["train-prior", *tiny]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "runs" / "prior" / "weights.npz").is_file()
    assert str(tmp_path / "runs" / "prior") in out and "--prior-weights" in out
    assert _sha(SHIPPED_WEIGHTS) == before


# ------------------------------------------------------------- --prior-weights


def test_prior_weights_are_recorded_and_other_weights_rebuild(tmp_path, capsys):
    from precompute import gqcnn

    params, arch, info = gqcnn.load_weights(SHIPPED_WEIGHTS)
    import jax

    other = tmp_path / "other.npz"
    gqcnn.save_weights(other, jax.tree_util.tree_map(lambda x: x * 0.5, params),
                       arch, info)  # fmt: skip
    path = _save(tmp_path, "box.obj", _box((0.05, 0.03, 0.02)))
    out = tmp_path / "p"
    base = ["--mesh", str(path), "--units", "m", "--out", str(out), "--trials", "1",
            "--grasps", "30", "--samples", "3", "--jobs", "1", "--quiet"]  # fmt: skip
    assert main([*base, "--prior", "learned"]) == 0
    dest = out / "custom" / "box.npz"
    meta = problem_mod.peek(dest)["meta"]
    assert meta["prior_weights"]["sha256"] == _sha(SHIPPED_WEIGHTS)
    q_shipped = problem_mod.load(dest).prior.copy()
    capsys.readouterr()
    assert main([*base, "--prior-weights", str(other)]) == 0
    assert "skipped" not in capsys.readouterr().out  # not taken as current
    meta = problem_mod.peek(dest)["meta"]
    assert meta["prior_weights"] == {"path": str(other), "sha256": _sha(other)}
    assert not np.array_equal(problem_mod.load(dest).prior, q_shipped)
    assert main([*base, "--prior-weights", str(other)]) == 0
    assert "skipped" in capsys.readouterr().out
    assert main([*base, "--prior-weights", str(tmp_path / "none.npz")]) == 2
    assert "no such prior weights file" in capsys.readouterr().err
    assert main([*base, "--prior-weights", str(other), "--prior", "synthetic"]) == 2
    assert "cannot go with --prior synthetic" in capsys.readouterr().err


@pytest.fixture(autouse=True)
def _no_stray_output():
    """No test here writes into the repository's committed folders."""
    before = (_sha(SUMMARY), _sha(SHIPPED_WEIGHTS))
    yield
    assert (_sha(SUMMARY), _sha(SHIPPED_WEIGHTS)) == before
