"""precompute: catalogue, mesh loading and refusals, stable poses, topple matrix."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from precompute import catalog
from precompute.errors import PrecomputeError
from precompute.mesh import egad_factor, load_mesh
from precompute.poses import (
    TILT_SIGMA_DEG,
    hull_model,
    stable_poses,
    tilt_directions,
    topple_matrix,
)


def _box(extents, translate=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents)
    m.apply_translation(translate)
    return m


def _poses_of(mesh, **kw):
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    hull = hull_model(v, f, np.asarray(mesh.center_mass))
    return hull, stable_poses(hull, v, f, **kw)


def _rect_solid_angle(p, q, d):
    """Solid angle of a p×q-half-sided rectangle seen from distance d above its
    centre (exact)."""
    return 4.0 * np.arcsin(p * q / np.sqrt((p * p + d * d) * (q * q + d * d)))


# ------------------------------------------------------------------ catalogue


def test_catalogue_has_the_62_objects_in_a_stable_order():
    infos = catalog.objects()
    assert len(infos) == 62
    assert len(catalog.objects("dexnet_adv")) == 13
    assert len(catalog.objects("egad_eval")) == 49
    assert [i.object_id for i in infos] == list(range(62))
    assert infos[0].name == "bar_clamp" and infos[13].name == "A0"
    assert all(i.mesh_path.is_file() for i in infos)
    assert {i.units for i in catalog.objects("egad_eval")} == {"mm"}
    assert catalog.lookup("C3").set == "egad_eval"
    names = [i.name for i in catalog.resolve(["F6", "dexnet_adv", "bar_clamp"])]
    assert names[:13] == [i.name for i in catalog.objects("dexnet_adv")]
    assert names[13:] == ["F6"]


def test_unknown_object_or_set_is_refused_with_a_suggestion():
    with pytest.raises(PrecomputeError, match="unknown object 'bar_clmap'.*bar_clamp"):
        catalog.lookup("bar_clmap")
    with pytest.raises(PrecomputeError, match="unknown set 'egad'"):
        catalog.objects("egad")


# ---------------------------------------------------------------- mesh loading


def _write(tmp_path, name, mesh=None, text=None):
    path = tmp_path / name
    if mesh is not None:
        mesh.export(path)
    else:
        path.write_text(text)
    return path


@pytest.mark.parametrize(
    "name, text, defect",
    [
        ("empty.obj", "", "empty file"),
        ("blank.obj", "   \n\n", "empty file"),
        ("words.obj", "hello\nthis is not a mesh\n", "not a mesh"),
        ("notes.txt", "v 0 0 0\n", "not a mesh file"),
        (
            "flat.obj",
            "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0.1 0.1 0\nf 1 2 3\nf 2 4 3\n",
            "degenerate: all points lie on a plane",
        ),
        (
            "line.obj",
            "v 0 0 0\nv 0.05 0 0\nv 0.1 0 0\nf 1 2 3\n",
            "degenerate",
        ),
    ],
)
def test_bad_mesh_files_are_refused_naming_file_and_defect(
    tmp_path, name, text, defect
):
    path = _write(tmp_path, name, text=text)
    with pytest.raises(PrecomputeError) as info:
        load_mesh(path, "m")
    msg = str(info.value)
    assert str(path) in msg and defect in msg
    assert "\n" not in msg


def test_missing_file_and_unknown_unit(tmp_path):
    with pytest.raises(PrecomputeError, match="no such file"):
        load_mesh(tmp_path / "nope.obj", "m")
    path = _write(tmp_path, "box.obj", _box((0.04, 0.06, 0.03)))
    with pytest.raises(PrecomputeError, match="unknown unit 'inch'"):
        load_mesh(path, "inch")


def test_open_surface_without_volume_is_refused(tmp_path):
    sphere = trimesh.creation.icosphere(2, 0.05)
    cap = sphere.copy()
    cap.update_faces(sphere.triangles_center[:, 2] > 0.0)
    cap.remove_unreferenced_vertices()
    path = _write(tmp_path, "cap.obj", cap)
    with pytest.raises(PrecomputeError, match="cap.obj: holes that cannot be closed"):
        load_mesh(path, "m")


def test_separate_bodies_are_refused(tmp_path):
    two = trimesh.util.concatenate(
        [_box((0.04, 0.04, 0.04)), _box((0.04, 0.04, 0.04), (0.2, 0, 0))]
    )
    path = _write(tmp_path, "two.obj", two)
    with pytest.raises(PrecomputeError, match="2 separate bodies"):
        load_mesh(path, "m")


def test_millimetres_read_as_metres_is_refused_with_a_hint(tmp_path):
    path = _write(tmp_path, "mm.obj", _box((40.0, 60.0, 30.0)))
    with pytest.raises(PrecomputeError, match=r"implausible size.*--units mm"):
        load_mesh(path, "m")
    mesh = load_mesh(path, "mm")
    assert np.allclose(np.ptp(mesh.vertices, axis=0), [0.04, 0.06, 0.03])
    assert mesh.scale == 0.001


def test_repairs_are_made_and_recorded(tmp_path):
    box = _box((0.04, 0.06, 0.03))
    flipped = box.copy()
    flipped.invert()
    m = load_mesh(_write(tmp_path, "flipped.obj", flipped), "m")
    assert any("inside-out" in r for r in m.repairs)
    assert m.trimesh().volume == pytest.approx(0.04 * 0.06 * 0.03)

    stray = trimesh.util.concatenate([box, _box((0.001,) * 3, (0.1, 0, 0))])
    m = load_mesh(_write(tmp_path, "stray.obj", stray), "m")
    assert any("stray piece" in r for r in m.repairs)
    assert np.ptp(m.vertices, axis=0).max() == pytest.approx(0.06)

    holed = box.copy()
    holed.update_faces(np.arange(10))
    holed.remove_unreferenced_vertices()
    m = load_mesh(_write(tmp_path, "holed.obj", holed), "m")
    assert any("closed holes" in r for r in m.repairs)
    assert m.trimesh().is_watertight

    overlap = trimesh.util.concatenate([box, _box((0.04, 0.06, 0.03), (0.02, 0, 0))])
    m = load_mesh(_write(tmp_path, "overlap.obj", overlap), "m")
    assert any("joined 2" in r for r in m.repairs)
    assert m.trimesh().volume == pytest.approx(0.06 * 0.06 * 0.03, rel=1e-6)


def test_every_shipped_mesh_loads_watertight():
    for info in catalog.objects("dexnet_adv"):
        m = load_mesh(info.mesh_path, info.units)
        tm = m.trimesh()
        assert tm.is_watertight and tm.volume > 0, info.name


# ------------------------------------------------------------- EGAD's size rule


def test_egad_rule_by_hand():
    # largest side -> 80 mm; the smallest then 56 mm, under the 64 mm cap
    assert egad_factor((100.0, 90.0, 70.0), 80.0) == pytest.approx(0.8)
    # 100 x 95 x 90 would become 80 x 76 x 72: the smallest side is capped at 64
    assert egad_factor((90.0, 100.0, 95.0), 80.0) == pytest.approx(64.0 / 90.0)


def test_egad_like_mesh_is_scaled_to_the_gripper(tmp_path):
    box = _box((100.0, 90.0, 70.0))
    # turned out of the axes: the rule reads the oriented bounding box
    box.apply_transform(trimesh.transformations.rotation_matrix(0.6, [1, 2, 3]))
    path = _write(tmp_path, "egad_like.obj", box)
    m = load_mesh(path, "mm", fit="egad")
    ext = np.sort(trimesh.bounds.oriented_bounds(m.trimesh())[1])
    assert ext == pytest.approx([0.056, 0.072, 0.080], abs=1e-9)
    assert m.scale == pytest.approx(0.0008) and m.fit == "egad"
    plain = load_mesh(path, "mm")  # no rule: the file's size
    assert plain.scale == 0.001
    with pytest.raises(PrecomputeError, match="unknown size rule 'big'"):
        load_mesh(path, "mm", fit="big")


def test_catalogue_sizes_egad_by_its_rule_and_keeps_dexnet():
    assert {i.fit for i in catalog.objects("egad_eval")} == {"egad"}
    assert {i.fit for i in catalog.objects("dexnet_adv")} == {"none"}
    for name in ("A0", "C0", "G6"):
        info = catalog.lookup(name)
        m = load_mesh(info.mesh_path, info.units, info.fit)
        ext = np.sort(trimesh.bounds.oriented_bounds(m.trimesh())[1])
        assert ext[2] <= 0.080 + 1e-6 and ext[0] <= 0.064 + 1e-6, name
        assert ext[2] == pytest.approx(0.080, abs=1e-6) or ext[0] == pytest.approx(
            0.064, abs=1e-6
        )


# --------------------------------------------------------------- stable poses


def test_box_has_its_analytic_stable_poses_and_probabilities():
    a, b, c = 0.02, 0.04, 0.08
    hull, sp = _poses_of(_box((a, b, c)), threshold=0.0)
    # one pose per pair of opposite faces: they look the same from above
    assert len(sp.landing) == 3
    assert [len(m) for m in sp.members] == [2, 2, 2]
    expect = np.array(
        [
            2 * _rect_solid_angle(b / 2, c / 2, a / 2),  # on a b×c face
            2 * _rect_solid_angle(a / 2, c / 2, b / 2),
            2 * _rect_solid_angle(a / 2, b / 2, c / 2),
        ]
    ) / (4 * np.pi)
    assert np.allclose(sp.landing, expect, atol=1e-9)
    assert np.isclose(hull.solid_angle.sum(), 4 * np.pi)
    # resting face on the table, centre of mass above the origin at its height
    for tf, h in zip(sp.transforms, [a / 2, b / 2, c / 2], strict=True):
        assert np.isclose(tf[2, 3], h)
        assert np.allclose(tf[:3, :3] @ tf[:3, :3].T, np.eye(3))
    # without merging: the six faces, each half of its pair
    _, sp6 = _poses_of(_box((a, b, c)), threshold=0.0, merge=False)
    assert len(sp6.landing) == 6
    assert np.allclose(np.sort(sp6.landing), np.sort(np.repeat(expect / 2, 2)))


def test_small_poses_are_dropped_and_landing_renormalised():
    a, b, c = 0.01, 0.05, 0.12  # standing on end is rare
    _, full = _poses_of(_box((a, b, c)), threshold=0.0)
    _, cut = _poses_of(_box((a, b, c)), threshold=0.05)
    assert full.landing.min() < 0.05
    assert len(cut.landing) == len(full.landing) - 1
    assert np.isclose(cut.landing.sum(), 1.0)
    assert np.isclose(cut.dropped_mass, full.landing.min())
    assert np.allclose(cut.landing, full.landing[:-1] / full.landing[:-1].sum())


def test_an_unstable_face_topples_onto_its_neighbour():
    # prism on the obtuse triangle (0,0), (0.1,0), (0.12,0.02), 0.03 deep: resting
    # on the short side next to the 135° corner, the centre of mass hangs over the
    # corner, so that side rolls onto the long bottom side (y = 0)
    tri = np.array([[0.0, 0.0], [0.1, 0.0], [0.12, 0.02]])
    pts = np.array([[x, y, z] for x, y in tri for z in (0.0, 0.03)])
    prism = trimesh.convex.convex_hull(pts)
    _, sp = _poses_of(prism, threshold=0.0, merge=False)
    short = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)  # its outward normal
    bottom = np.array([0.0, -1.0, 0.0])
    dots = sp.normals @ short
    assert dots.max() < 0.99  # the short side is not a stable pose
    s_bottom = int(np.argmax(sp.normals @ bottom))
    # independent check: fraction of gravity rays from the centre of mass that
    # pierce the bottom or the short side first (ray casting on the mesh)
    rng = np.random.default_rng(0)
    u = rng.normal(size=(100_000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    com = np.asarray(prism.center_mass)
    tri_idx = prism.ray.intersects_first(np.repeat(com[None], len(u), 0), u)
    normals = prism.face_normals[tri_idx]
    into = (normals @ bottom > 0.999) | (normals @ short > 0.999)
    assert sp.landing[s_bottom] == pytest.approx(into.mean(), abs=0.005)


@pytest.mark.parametrize("name", ["bar_clamp", "endstop_holder", "nozzle"])
def test_stable_poses_match_trimesh(name):
    info = catalog.lookup(name)
    mesh = load_mesh(info.mesh_path, info.units)
    tm = mesh.trimesh()
    _, sp = _poses_of(tm, threshold=0.0, merge=False)
    tfs, probs = trimesh.poses.compute_stable_poses(tm)
    ours = {
        tuple(np.round(-n, 2)): p for n, p in zip(sp.normals, sp.landing, strict=True)
    }
    theirs = {}
    for tf, p in zip(tfs, probs, strict=True):
        up = tuple(np.round(tf[2, :3], 2))  # mesh-frame direction that points up
        theirs[up] = theirs.get(up, 0.0) + p
    big = {k: v for k, v in theirs.items() if v > 1e-3}
    for key, p in big.items():
        assert key in ours, (name, key)
        assert ours[key] == pytest.approx(p, abs=2e-3), (name, key)
    assert sum(v for k, v in ours.items() if k in big) == pytest.approx(
        sum(big.values()), abs=5e-3
    )


def test_turned_part_merges_its_symmetric_side_poses():
    # a hexagonal prism lying on its sides: six congruent side poses -> one
    prism = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=6)
    _, sp = _poses_of(prism, threshold=0.0)
    sizes = sorted(len(m) for m in sp.members)
    assert sizes == [2, 6]  # the two end faces, the six sides
    assert np.isclose(sp.landing.sum(), 1.0)


# ------------------------------------------------------------------ topple


def test_cube_never_topples_under_small_tilts():
    hull, sp = _poses_of(_box((0.05, 0.05, 0.05)))
    T = topple_matrix(hull, sp)
    assert T.shape == (1, 1) and T[0, 0] == 1.0


def test_standing_box_topples_as_often_as_the_tilt_grid_says():
    a, c = 0.03, 0.12  # a×a×c box standing on its a×a end
    box = _box((a, a, c))
    hull, sp = _poses_of(box, threshold=0.0)
    T = topple_matrix(hull, sp)
    assert np.allclose(T.sum(axis=1), 1.0)
    stand = int(np.argmax([tf[2, 3] for tf in sp.transforms]))
    lie = [s for s in range(len(sp.landing)) if s != stand]
    # the end topples exactly when the tilted gravity ray from the centre of mass
    # leaves the a×a end face: |tan θ (cos φ, sin φ)| beyond a/c along an axis
    g = tilt_directions(sp.normals[stand])  # mesh frame; the end's normal is ±z
    n = sp.normals[stand]
    along = g @ n
    off = g - along[:, None] * n
    x, y = np.abs(off[:, 0]) / along, np.abs(off[:, 1]) / along
    expect = np.mean((x > a / c) | (y > a / c))
    assert 1.0 - T[stand, stand] == pytest.approx(expect, abs=1e-12)
    assert 0.1 < expect < 0.9  # the test means something with σ = 15°
    assert TILT_SIGMA_DEG == 15.0
    assert T[stand, lie].sum() == pytest.approx(1.0 - T[stand, stand])
    for s in lie:  # lying poses are stable under the same tilts
        assert T[s, s] > 0.95
