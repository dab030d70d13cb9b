"""precompute: grasps, ground truth, prior, build determinism, cache, CLI."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import catalog_problem, run_module

import precompute
from precompute import grasps as G
from precompute import prior as Q
from precompute.analysis import prior_only_gaps, top_by_prior
from precompute.build import (
    STREAM_PRIOR,
    BuildParams,
    _rng,
    build_problem,
    read_meta,
)
from precompute.raycast import RayCaster, face_pad_normals

REPO = Path(__file__).resolve().parent.parent


def _table_box(extents):
    """Box resting on the table (z = 0), centred at the origin in x, y."""
    m = trimesh.creation.box(extents)
    m.apply_translation((0.0, 0.0, extents[2] / 2))
    caster = RayCaster(np.asarray(m.vertices), np.asarray(m.faces))
    return caster, G.height_map(caster)


def _p(caster, hmap, centers, axes, samples=400, seed=0):
    centers = np.atleast_2d(np.asarray(centers, float))
    axes = np.broadcast_to(np.asarray(axes, float), centers.shape)
    rng = np.random.default_rng(seed)
    return G.robustness(
        caster, hmap, centers, axes, *G.perturbations(rng, len(centers), samples)
    )


# --------------------------------------------------------------- ground truth


def test_centred_box_grasp_is_robust_and_fails_past_the_edge():
    # squeeze a 40 mm wide box across its two x faces, sliding along y towards
    # and past the end face at y = 30 mm
    caster, hmap = _table_box((0.04, 0.06, 0.03))
    offsets = np.array([0.0, 0.02, 0.03, 0.04, 0.05])
    centers = np.stack([0 * offsets, offsets, np.full(5, 0.015)], axis=1)
    p = _p(caster, hmap, centers, [1.0, 0.0, 0.0])
    # 400 samples: standard error at most 0.025
    assert p[0] > 0.97
    assert p[1] > 0.8
    assert 0.25 < p[2] < 0.75  # on the edge: half the samples miss the box
    assert p[4] < 0.05
    assert np.all(np.diff(p) < 0.03)  # falls as the grasp moves past the edge


def test_grasp_across_slanted_faces_fails_for_low_friction():
    # a grasp whose jaw axis meets the faces at 40° is outside the friction cone of
    # μ ≈ 0.5 (26.6°): almost never in force closure
    caster, hmap = _table_box((0.04, 0.06, 0.03))
    yaw = np.deg2rad(40.0)
    p = _p(caster, hmap, [0.0, 0.0, 0.015], [np.cos(yaw), np.sin(yaw), 0.0])
    assert p[0] < 0.05


def test_grasp_wider_than_the_opening_fails_and_never_enters_a_reservoir():
    # every chord of a 100 x 120 mm box narrower than 80 mm crosses a corner, where
    # the two contacts are on faces at 90 degrees: never antipodal at mu = 0.6
    caster, hmap = _table_box((0.1, 0.12, 0.03))
    ex = G.execute(caster, hmap, np.array([[0.0, 0.0, 0.015]]), np.array([[1, 0, 0.0]]))
    assert not ex.ok[0]
    res = G.sample_reservoir(caster, hmap, 300, np.random.default_rng(0))
    assert res.valid.sum() == 0
    assert res.candidates == G.MAX_ROUNDS * 600  # it tried every round


def _faces_hit(box, points, directions):
    """Outward normal of the first face of trimesh's box met by each ray (trimesh's
    own ray casting, independent of Embree)."""
    locs, rays, tri = box.ray.intersects_location(points, directions)
    first = np.full(len(points), -1)
    best = np.full(len(points), np.inf)
    dist = np.einsum("ij,ij->i", locs - points[rays], directions[rays])
    for r, d, t in zip(rays, dist, tri, strict=True):
        if d < best[r]:
            best[r], first[r] = d, t
    assert (first >= 0).all()
    return box.face_normals[first]


def test_box_reservoir_squeezes_opposite_faces_inside_the_friction_cone():
    extents = (0.04, 0.06, 0.03)
    caster, hmap = _table_box(extents)
    res = G.sample_reservoir(caster, hmap, 400, np.random.default_rng(3))
    assert res.valid.all()
    c, a, w = res.center, res.axis, res.width
    box = trimesh.creation.box(extents)
    box.apply_translation((0, 0, extents[2] / 2))
    # each jaw, from its open position, meets a face: those faces are opposite
    n1 = _faces_hit(box, c - G.OPENING / 2 * a, a)
    n2 = _faces_hit(box, c + G.OPENING / 2 * a, -a)
    assert np.allclose(n1, -n2)
    assert np.allclose(n1[:, 2], 0.0)  # side faces, never the top
    # and the jaw axis is inside the friction cone at the sampling friction
    cone = np.arctan(G.SAMPLING_FRICTION)
    angle = np.arccos(np.clip(-np.einsum("ij,ij->i", n1, a), -1, 1))
    assert angle.max() <= cone + 1e-6
    # the squeeze is across the 40 mm or the 60 mm width of the box
    assert np.all(np.isclose(w, 0.04 / np.cos(angle), atol=2e-4)
                  | np.isclose(w, 0.06 / np.cos(angle), atol=2e-4))  # fmt: skip
    # both widths occur (both pairs of side faces are sampled)
    assert (w < 0.05).any() and (w > 0.055).any()


def test_pad_normals_of_a_rough_sphere_point_to_its_centre():
    # a 40 mm sphere (edges about 3 mm) whose vertices are moved radially by up
    # to 1 mm: facets turn by 16 degrees between neighbours, as on EGAD's G6 (14)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.04)
    rng = np.random.default_rng(0)
    r = 1.0 + rng.uniform(-0.001, 0.001, (len(sphere.vertices), 1)) / 0.04
    v = np.asarray(sphere.vertices) * r
    rough = trimesh.Trimesh(v, sphere.faces, process=False)
    assert 12 < np.degrees(np.median(rough.face_adjacency_angles)) < 20
    centre = v[sphere.faces].mean(axis=1)
    radial = centre / np.linalg.norm(centre, axis=1, keepdims=True)

    def mean_angle(n):
        return np.degrees(np.arccos(np.clip((n * radial).sum(1), -1, 1))).mean()

    pad = face_pad_normals(v, sphere.faces, G.PAD_RADIUS)
    assert mean_angle(pad) < 3.0
    assert mean_angle(rough.face_normals) > 3 * mean_angle(pad)
    # contacts found by closing the jaws carry the pad normal of the face hit
    caster = RayCaster(v + [0, 0, 0.04], sphere.faces)
    hmap = G.height_map(caster)
    # 25 mm above the centre the chord is 62 mm: the open jaws clear the sphere
    ex = G.execute(caster, hmap, np.array([[0.0, 0.0, 0.065]]), np.array([[1, 0, 0.0]]))
    assert ex.ok[0]
    x1 = ex.x1[0] - [0, 0, 0.04]
    assert np.degrees(np.arccos(np.dot(ex.n1[0], x1 / np.linalg.norm(x1)))) < 8.0


def test_pad_normals_of_flat_faces_are_the_face_normals():
    box = trimesh.creation.box((0.05, 0.03, 0.02))
    pad = face_pad_normals(box.vertices, box.faces, G.PAD_RADIUS)
    assert np.allclose(pad, box.face_normals, atol=1e-12)
    # a thin wall: the far side's faces (2 mm away) do not cancel the near side's
    wall = trimesh.creation.box((0.002, 0.04, 0.04))
    wall = wall.subdivide().subdivide()
    pad = face_pad_normals(wall.vertices, wall.faces, G.PAD_RADIUS)
    side = np.abs(wall.face_normals[:, 0]) > 0.99
    assert np.allclose(pad[side], wall.face_normals[side], atol=1e-9)


def test_fingers_and_palm_collisions():
    caster, hmap = _table_box((0.04, 0.06, 0.1))  # 100 mm tall
    c = np.array([[0.0, 0.0, 0.08], [0.0, 0.0, 0.03], [0.0, 0.0, 0.001]])
    ex = G.execute(caster, hmap, c, np.array([[1.0, 0.0, 0.0]] * 3))
    # near the top: fine; 30 mm up a 100 mm box the palm hits its top; a finger
    # tip under the table is a collision
    assert ex.ok.tolist() == [True, False, False]


def test_reservoirs_of_a_real_object_hold_good_and_bad_grasps():
    pb = catalog_problem("endstop_holder", trials=1, grasps=300, samples=50)
    p = pb.robustness[pb.valid]
    assert pb.valid.sum(axis=-1).min() == 300
    # antipodal grasps, yet perturbation separates them: both tails are populated
    assert (p >= 0.8).mean() > 0.1
    assert (p <= 0.3).mean() > 0.1
    assert p.std() > 0.15
    assert np.all(pb.grasp_width[pb.valid] <= G.OPENING)
    assert np.all(pb.grasp_height[pb.valid] >= G.MIN_HEIGHT)


# ---------------------------------------------------------------------- prior


def test_prior_is_seeded_per_slot_and_follows_p():
    params = BuildParams()
    a = Q.prior_noise(_rng(params, "x", 2, 3, STREAM_PRIOR), 100)
    b = Q.prior_noise(_rng(params, "x", 2, 3, STREAM_PRIOR), 40)
    assert np.array_equal(a[:40], b)  # a slot's draw does not depend on K
    c = Q.prior_noise(_rng(params, "x", 2, 4, STREAM_PRIOR), 100)
    assert not np.array_equal(a, c)
    p = np.linspace(0, 1, 100)
    q = Q.prior_from_noise(p, np.zeros(100))
    assert np.all(np.diff(q) > 0) and 0 < q.min() and q.max() < 1
    # statistically: correlated with p, imperfect
    rng = np.random.default_rng(0)
    p = rng.random(20000)
    q = Q.prior_from_noise(p, rng.standard_normal(20000))
    r = np.corrcoef(p, q)[0, 1]
    assert 0.15 < r < 0.6
    assert Q.prior_params()["synthetic"] is True


def test_prior_only_gaps_match_a_hand_computation():
    landing = np.array([0.75, 0.25])
    rob = np.array([[[0.1, 0.9, 0.5], [0.2, 0.0, 0.0]]])
    prior = np.array([[[0.8, 0.1, 0.5], [0.3, 0.9, 0.0]]])
    valid = np.array([[[True, True, True], [True, True, False]]])
    g = prior_only_gaps(landing, rob, prior, valid, k=2)
    # pose 0: p* 0.9, greedy picks p=0.1; top-2 by q = {0, 2} -> best p 0.5
    # pose 1: p* 0.2, greedy picks p=0.0; top-2 = {1, 0} -> 0.2
    assert g["greedy"][0] == pytest.approx(0.75 * 0.8 + 0.25 * 0.2)
    assert g["top"][0] == pytest.approx(0.75 * 0.4 + 0.25 * 0.0)
    assert top_by_prior(prior, valid, 3)[0, 1].tolist() == [1, 0, -1]


# ------------------------------------------------------------ build and cache


def _small():
    # the synthetic prior: these tests change its constants
    return BuildParams(trials=2, grasps=60, samples=20, prior="synthetic")


def test_build_is_byte_identical_and_seeded(tmp_path):
    from legs_jax.core.problem import load, save

    info = precompute.catalog.lookup("bar_clamp")

    def make(seed, name):
        pb = build_problem(
            info.mesh_path,
            units="m",
            name="bar_clamp",
            params=BuildParams(
                trials=2, grasps=60, samples=20, seed=seed, prior="synthetic"
            ),
        )
        return save(pb, tmp_path / name)

    a, b, c = make(0, "a.npz"), make(0, "b.npz"), make(1, "c.npz")
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    pb = load(a)
    assert pb.meta["prior"]["synthetic"] is True
    assert "synthetic" in pb.meta["prior_label"]
    assert pb.meta["mesh_file"] == "data/meshes/dexnet_adv/bar_clamp.obj"
    # a synthetic build records its prior as files did before the learned prior
    # existed, so those files (and results pinned to their SHA-256) stay current
    assert "prior_kind" not in pb.meta and "prior" not in pb.meta["params"]
    assert np.allclose(pb.topple.sum(axis=1), 1.0, atol=1e-5)
    assert pb.landing.sum() == pytest.approx(1.0, abs=1e-5)


def test_a_new_prior_constant_recomputes_only_the_prior(tmp_path, monkeypatch):
    import precompute.build as B

    mesh = _tiny_catalogue(tmp_path)
    assert mesh.is_file()
    path = precompute.ensure(
        ["brick"], data_dir=tmp_path, progress=False, jobs=1, params=_small()
    )["brick"]
    before = np.load(path)
    monkeypatch.setattr(Q, "NOISE", Q.NOISE * 0.5)
    monkeypatch.setattr(B, "build_problem", None)  # a full build would fail
    precompute.ensure(["brick"], data_dir=tmp_path, progress=False, params=_small())
    after = np.load(path)
    assert np.array_equal(before["robustness"], after["robustness"])
    assert not np.array_equal(before["prior"], after["prior"])
    assert read_meta(path)["prior"]["noise"] == Q.NOISE
    monkeypatch.undo()
    monkeypatch.setattr(Q, "NOISE", Q.NOISE * 0.5)
    # byte-identical to a full build with the new constant
    fresh = tmp_path / "fresh"
    shutil.copytree(tmp_path / "meshes", fresh / "meshes")
    path2 = precompute.ensure(
        ["brick"], data_dir=fresh, progress=False, jobs=1, params=_small()
    )["brick"]
    assert path2.read_bytes() == path.read_bytes()


def _tiny_catalogue(root: Path) -> Path:
    folder = root / "meshes" / "dexnet_adv"
    folder.mkdir(parents=True)
    box = trimesh.creation.box((0.03, 0.05, 0.02))
    box.export(folder / "brick.obj")
    return folder / "brick.obj"


def test_ensure_builds_once_and_rebuilds_when_the_mesh_changes(tmp_path):
    mesh = _tiny_catalogue(tmp_path)
    paths = precompute.ensure(
        ["brick"], data_dir=tmp_path, progress=False, jobs=1, params=_small()
    )
    path = paths["brick"]
    # a prior other than the default one (learned, with its weights shipped) is
    # kept in its own subfolder
    assert (
        path == tmp_path / "problems" / "prior-synthetic" / "dexnet_adv" / "brick.npz"
    )
    first = path.stat().st_mtime_ns
    precompute.ensure(["brick"], data_dir=tmp_path, progress=False, params=_small())
    assert path.stat().st_mtime_ns == first  # up to date: not rebuilt
    old_hash = read_meta(path)["build_hash"]
    trimesh.creation.box((0.03, 0.05, 0.025)).export(mesh)
    precompute.ensure(
        ["dexnet_adv"], data_dir=tmp_path, progress=False, params=_small()
    )
    assert read_meta(path)["build_hash"] != old_hash
    # other parameters are another build
    precompute.ensure(
        ["brick"],
        data_dir=tmp_path,
        progress=False,
        params=BuildParams(trials=1, grasps=30, samples=10, prior="synthetic"),
    )
    assert read_meta(path)["params"]["grasps"] == 30
    with pytest.raises(precompute.PrecomputeError, match="unknown object 'brik'"):
        precompute.ensure(["brik"], data_dir=tmp_path, progress=False)


# ------------------------------------------------------------------------ CLI


def _cli(*args, cwd=REPO):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return run_module("precompute", args, cwd=cwd, env=env, timeout=120)


def test_cli_help_and_clear_errors(tmp_path):
    r = _cli("--help")
    assert r.returncode == 0 and "--mesh" in r.stdout and "report" in r.stdout
    bad = tmp_path / "broken.obj"
    bad.write_text("")
    r = _cli("--mesh", str(bad), "--units", "mm", "--out", str(tmp_path), "--quiet")
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {bad}: empty file"
    assert "Traceback" not in r.stderr
    r = _cli("--mesh", str(bad))
    assert r.returncode == 2 and "needs --units" in r.stderr
    r = _cli("--object", "pwan", "--out", str(tmp_path))
    assert r.returncode == 2 and "did you mean pawn" in r.stderr
    r = _cli("--object", "pawn", "--grasps", "0", "--out", str(tmp_path))
    assert r.returncode == 2 and "--grasps must be at least 1" in r.stderr


def test_cli_builds_a_users_mesh_in_millimetres(tmp_path):
    from legs_jax.core.problem import load

    mesh = tmp_path / "my_part.stl"
    trimesh.creation.box((30.0, 50.0, 20.0)).export(mesh)
    args = ["--mesh", str(mesh), "--units", "mm", "--out", str(tmp_path / "out")]
    r = _cli(*args, "--trials", "1", "--grasps", "40", "--samples", "10", "--quiet")
    assert r.returncode == 0, r.stderr
    pb = load(tmp_path / "out" / "custom" / "my_part.npz")
    assert pb.meta["mesh_scale"] == 0.001 and pb.meta["units"] == "mm"
    assert pb.num_real_poses == 3
    # metres: no chord of a 30 x 50 x 20 mm box is longer than its diagonals
    assert 0 < pb.grasp_width[pb.valid].min()
    assert pb.grasp_width[pb.valid].max() <= np.hypot(0.05, 0.03) + 1e-4
    # without --out, from the user's own folder: ./problems there, never data/
    work = tmp_path / "work"
    work.mkdir()
    args = ["--mesh", str(mesh), "--units", "mm", "--trials", "1", "--grasps", "20"]
    r = _cli(*args, "--samples", "5", "--quiet", cwd=work)
    assert r.returncode == 0, r.stderr
    dest = work / "problems" / "custom" / "my_part.npz"
    assert dest.is_file() and str(dest) in r.stdout


def test_cli_fit_egad_scales_a_users_mesh(tmp_path):
    from legs_jax.core.problem import load

    mesh = tmp_path / "blob.stl"
    trimesh.creation.box((100.0, 90.0, 70.0)).export(mesh)
    args = ["--mesh", str(mesh), "--units", "mm", "--fit", "egad"]
    r = _cli(*args, "--out", str(tmp_path / "o"), "--trials", "1", "--grasps", "20",
             "--samples", "5", "--quiet")  # fmt: skip
    assert r.returncode == 0, r.stderr
    pb = load(tmp_path / "o" / "custom" / "blob.npz")
    assert pb.meta["fit"] == "egad"
    assert pb.meta["mesh_scale"] == pytest.approx(0.0008)
    r = _cli("--object", "pawn", "--fit", "egad", "--out", str(tmp_path))
    assert r.returncode == 2 and "--fit applies to --mesh only" in r.stderr


@pytest.mark.slow
def test_full_scale_object_meets_the_issue_shape():
    info = precompute.catalog.lookup("bar_clamp")
    pb = build_problem(info.mesh_path, units=info.units, name=info.name)
    assert pb.robustness.shape[0] == 10 and pb.robustness.shape[2] == 2000
    assert pb.valid.all()
    p = pb.robustness[pb.valid]
    assert (p >= 0.5).any() and (p < 0.1).any()


@pytest.mark.slow
def test_parallel_build_equals_serial(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for out, jobs in ((a, "1"), (b, "2")):
        r = _cli("--object", "nozzle", "F6", "--trials", "2", "--grasps", "200",
                 "--out", str(out), "--jobs", jobs, "--quiet")  # fmt: skip
        assert r.returncode == 0, r.stderr
    for rel in ("dexnet_adv/nozzle.npz", "egad_eval/F6.npz"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes()
    shutil.rmtree(a)
