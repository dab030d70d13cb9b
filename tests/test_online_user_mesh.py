"""A problem file of the user's own mesh (python -m precompute --mesh) finds its
mesh where it was built, from another folder and after the file is moved, by
what its meta records; one clear line when it cannot."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import run_module

from legs_jax.core import problem as problem_mod
from legs_jax.online import cli
from legs_jax.online import simulate as sim_mod
from legs_jax.online.robot import World
from precompute.errors import PrecomputeError

ROOT = Path(__file__).resolve().parents[1]
SIZE = (40.0, 60.0, 30.0)  # mm


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    """(problem file, mesh): work/meshes/duck.stl built from work/ into
    work/problems/custom/duck.npz."""
    work = tmp_path_factory.mktemp("user") / "work"
    (work / "meshes").mkdir(parents=True)
    mesh = work / "meshes" / "duck.stl"
    trimesh.creation.box(SIZE).export(mesh)
    args = ["--mesh", "meshes/duck.stl", "--units", "mm", "--trials", "1"]
    args += ["--grasps", "100", "--samples", "5", "--quiet", "--prior", "synthetic"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = run_module("precompute", args, cwd=work, env=env)
    assert r.returncode == 0, r.stderr
    return work / "problems" / "custom" / "duck.npz", mesh


def _extent(world: World) -> list[float]:
    return sorted(np.ptp(world.vertices, axis=0).round(6).tolist())


def _moved(problem: Path, dest: Path, **meta) -> Path:
    """A copy of the problem file at ``dest`` with ``meta`` entries changed
    (None: removed)."""
    pb = problem_mod.load(problem)
    new = {k: v for k, v in {**pb.meta, **meta}.items() if v is not None}
    dest.parent.mkdir(parents=True, exist_ok=True)
    return problem_mod.save(dataclasses.replace(pb, meta=new), dest)


def test_the_mesh_is_found_from_another_folder(built, tmp_path, monkeypatch):
    """Run from elsewhere: the mesh in a subfolder of where precompute ran is
    found by its recorded name, and a decoy of the same name (another mesh)
    beside the build is passed over by its SHA-256."""
    problem, mesh = built
    monkeypatch.chdir(tmp_path)
    decoy = problem.parents[2] / "duck.stl"
    trimesh.creation.box((10.0, 10.0, 10.0)).export(decoy)
    try:
        world = World.from_problem(problem_mod.load(problem), problem_path=problem)
    finally:
        decoy.unlink()
    want = sorted(x / 1000 for x in SIZE)
    assert _extent(world) == pytest.approx(want)
    assert world.num_poses == int(problem_mod.load(problem).pose_valid.sum())


def test_a_moved_problem_file_finds_its_mesh_by_its_recorded_path(
    built, tmp_path, monkeypatch
):
    problem, mesh = built
    monkeypatch.chdir(tmp_path)
    want = sorted(x / 1000 for x in SIZE)
    away = tmp_path / "else" / "where" / "deep"
    # the name alone: not found from here, in one line naming --object MESH
    lone = _moved(
        problem, away / "a" / "duck.npz", mesh_file="duck.stl", mesh_file_abs=None
    )
    with pytest.raises(PrecomputeError) as e:
        World.from_problem(problem_mod.load(lone), problem_path=lone)
    assert "--object MESH" in str(e.value) and "\n" not in str(e.value)
    # an absolute path, a path relative to the problem file, another key
    rel = os.path.relpath(mesh, away / "b")
    for sub, meta in (
        ("a", {"mesh_file": str(mesh), "mesh_file_abs": None}),
        ("b", {"mesh_file": rel, "mesh_file_abs": None}),
        (
            "c",
            {
                "mesh_file": "duck.stl",
                "mesh_file_abs": None,
                "mesh_path_absolute": str(mesh),
            },
        ),
    ):
        moved = _moved(problem, away / sub / "duck.npz", **meta)
        world = World.from_problem(problem_mod.load(moved), problem_path=moved)
        assert _extent(world) == pytest.approx(want), meta
    # nothing recorded at all: the same clear line
    bare = _moved(problem, away / "d" / "duck.npz", mesh_file=None, mesh_file_abs=None)
    with pytest.raises(PrecomputeError, match="--object MESH"):
        World.from_problem(problem_mod.load(bare), problem_path=bare)


def test_simulate_runs_a_users_problem_file_from_another_folder(
    built, tmp_path, monkeypatch, capsys
):
    """simulate --object work/problems/custom/duck.npz from outside work/: the
    mesh is found and the run starts (killed at its first step here)."""
    problem, _ = built
    monkeypatch.chdir(problem.parents[3])
    rel = problem.relative_to(problem.parents[3])

    def killed(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(sim_mod.Simulation, "run_step", killed)
    args = ["simulate", "--object", str(rel), "--given-poses", "--quiet"]
    rc = cli.main([*args, "--compile-cache", "off", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert rc == 130 and "cannot find" not in err, err
    # moved away from the folder it was built in, with the name alone recorded:
    # one line that says what to do
    lone = _moved(
        problem,
        tmp_path / "moved" / "x" / "duck.npz",
        mesh_file="duck.stl",
        mesh_file_abs=None,
    )
    monkeypatch.chdir(tmp_path)
    rc = cli.main([*args[:2], str(lone), *args[3:], "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert rc == 2 and "give it as --object MESH" in err
    assert err.strip().count("\n") == 0 and "Traceback" not in err


def test_a_scaled_mesh_is_seen_at_its_scale(tmp_path):
    """A problem built with --scale: the online world holds the mesh at the size
    the problem was built at (and its recorded SHA-256 matches)."""
    work = tmp_path / "work"
    (work / "meshes").mkdir(parents=True)
    trimesh.creation.box(SIZE).export(work / "meshes" / "part.stl")
    args = ["--mesh", "meshes/part.stl", "--units", "mm", "--scale", "0.5"]
    args += ["--trials", "1", "--grasps", "100", "--samples", "5", "--quiet"]
    args += ["--prior", "synthetic"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = run_module("precompute", args, cwd=work, env=env)
    assert r.returncode == 0, r.stderr
    path = work / "problems" / "custom" / "part.npz"
    world = World.from_problem(problem_mod.load(path), problem_path=path)
    assert _extent(world) == pytest.approx(sorted(s / 2000.0 for s in SIZE))
