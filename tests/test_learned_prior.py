"""The learned prior: generated objects, depth images, crops, training,
scoring, and that q never depends on the ground truth."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from helpers import run_module

import precompute
from precompute import depth as D
from precompute import gqcnn as Q
from precompute import grasps as G
from precompute import learned
from precompute.build import BuildParams, build_hash, build_problem
from precompute.mesh import EGAD_MIN_SIDE
from precompute.raycast import RayCaster
from precompute.shapes import KINDS, generate

REPO = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------ generated objects


def _signature(mesh) -> np.ndarray:
    """Similarity-invariant numbers of a solid: the sorted principal second
    moments over V^(5/3) and the area over V^(2/3)."""
    v = abs(mesh.volume)
    inertia = np.asarray(mesh.moment_inertia)
    second = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    ev = np.sort(np.linalg.eigvalsh(second)) / v ** (5 / 3)
    return np.concatenate([ev, [mesh.area / v ** (2 / 3)]])


@pytest.fixture(scope="module")
def shapes():
    return [generate(i, seed=0) for i in range(30)]


def test_generated_objects_are_watertight_and_sized_by_egads_rule(shapes):
    assert {s.kind for s in shapes} == set(KINDS)
    for s in shapes:
        m = s.trimesh()
        assert m.is_watertight and m.is_winding_consistent, s.index
        assert m.volume > 0, s.index
        assert np.allclose(m.center_mass, 0.0, atol=1e-9)
        _, ext = trimesh.bounds.oriented_bounds(m)
        lo, hi = np.min(ext), np.max(ext)
        # largest side = opening, or smallest side capped at 0.8 opening
        assert hi <= G.OPENING + 1e-6 and lo <= EGAD_MIN_SIDE * G.OPENING + 1e-6
        assert np.isclose(hi, G.OPENING, atol=1e-6) or np.isclose(
            lo, EGAD_MIN_SIDE * G.OPENING, atol=1e-6
        ), (s.index, ext)


def test_generated_objects_are_seeded():
    a, b, c = generate(7, seed=0), generate(7, seed=0), generate(7, seed=1)
    assert a.vertices.tobytes() == b.vertices.tobytes()
    assert a.faces.tobytes() == b.faces.tobytes()
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(
        a.vertices, c.vertices
    )


def test_no_generated_object_is_an_evaluation_mesh(shapes):
    evals = precompute.catalog.objects()
    assert len(evals) == 62
    ref = np.stack([_signature(trimesh.load(i.mesh_path, force="mesh")) for i in evals])
    for s in shapes:
        sig = _signature(s.trimesh())
        rel = np.abs(ref - sig) / np.abs(ref)
        # the same solid at any size and turn would agree to rounding
        assert rel.max(axis=1).min() > 0.01, s.index
    # the check can see a match: an evaluation mesh, rescaled and turned
    m = trimesh.load(evals[0].mesh_path, force="mesh")
    m.apply_scale(0.37)
    m.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1, 2, 3]))
    assert (np.abs(ref[0] - _signature(m)) / np.abs(ref[0])).max() < 1e-6


# --------------------------------------------------------------- depth images


def _box_caster(size, offset):
    box = trimesh.creation.box(size)
    v = np.asarray(box.vertices) + np.array([offset[0], offset[1], size[2] / 2])
    return RayCaster(v, np.asarray(box.faces))


def test_render_gives_the_known_depth_of_a_box():
    size, off = (0.04, 0.06, 0.03), (0.01, -0.005)
    img = D.render(_box_caster(size, off))
    top = D.HEIGHT - size[2]

    def at(x, y, z):
        col, row = img.pixel_of(D.project(np.array([x, y, z])))
        return img.depth[int(round(row)), int(round(col))]

    assert at(off[0], off[1], size[2]) == pytest.approx(top, abs=1e-6)
    assert at(off[0] + 0.015, off[1] - 0.025, size[2]) == pytest.approx(top, abs=1e-6)
    assert at(off[0] + 0.03, off[1], 0.0) == pytest.approx(D.HEIGHT, abs=1e-6)
    # the top's edges x = -0.01 and 0.03 m seen from 0.67 m: u = cx + 525 x / 0.67
    row = int(round(img.pixel_of(D.project(np.array([off[0], off[1], size[2]])))[1]))
    u_lo = D.CENTER[0] + D.FOCAL * (off[0] - size[0] / 2) / (D.HEIGHT - size[2])
    u_hi = D.CENTER[0] + D.FOCAL * (off[0] + size[0] / 2) / (D.HEIGHT - size[2])
    cols = img.u0 + np.arange(img.depth.shape[1])
    on_top = img.depth[row] < D.HEIGHT - 1e-3
    assert np.all(on_top[(cols > u_lo + 0.6) & (cols < u_hi - 0.6)])
    assert not np.any(on_top[(cols < u_lo - 0.6) | (cols > u_hi + 0.6)])
    assert on_top.sum() == pytest.approx(u_hi - u_lo, abs=1.0)
    # the window holds the object and a margin, in whole 3 x 3 blocks
    h, w = img.depth.shape
    assert h % D.DOWNSAMPLE == 0 and w % D.DOWNSAMPLE == 0
    assert (img.depth == np.float32(D.HEIGHT))[[0, -1]].all()
    small = D.downsample(img)
    assert small.depth.shape == (h // 3, w // 3)
    assert small.depth.mean() == pytest.approx(img.depth.mean(), abs=1e-6)
    col, row = small.pixel_of(D.project(np.array([off[0], off[1], size[2]])))
    assert small.depth[int(round(row)), int(round(col))] == pytest.approx(top, 1e-6)


def test_sensor_noise_is_seeded_with_dexnets_spread_and_correlation():
    flat = D.DepthImage(np.full((48, 48), 0.7, np.float32), 0.0, 0.0, 3)
    rng = np.random.default_rng(0)
    draws = np.stack([D.add_noise(flat, rng).depth for _ in range(400)])
    a = D.add_noise(flat, np.random.default_rng(5)).depth
    b = D.add_noise(flat, np.random.default_rng(5)).depth
    assert a.tobytes() == b.tobytes()
    # at a grid node: 0.7 (g - 1) + N(0, 5 mm), g ~ Gamma(1000, 1/1000)
    node = draws[:, 8, 8] - 0.7
    expected = np.hypot(0.7 / np.sqrt(D.GAMMA_SHAPE), D.GP_SIGMA)
    assert node.std() == pytest.approx(expected, rel=0.12)  # 400 draws: ±3.5 % sd
    assert abs(node.mean()) < 4 * expected / np.sqrt(400)
    # correlated: neighbours differ far less than pixels 12 apart
    near = (draws[:, 20, 20] - draws[:, 20, 21]).std()
    far = (draws[:, 20, 20] - draws[:, 20, 32]).std()
    assert near < 0.3 * far
    assert far == pytest.approx(np.sqrt(2) * D.GP_SIGMA, rel=0.3)


# ---------------------------------------------------------------------- crops


def _edge_image(normal, high=0.65):
    """A resized image of a step: depth ``high`` where (x, y)·normal > 0, else the
    table."""
    n = 81
    img = D.DepthImage(np.zeros((n, n), np.float32), 319.5 - 120, 239.5 - 120, 3)
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    u = img.u0 + 3 * cols
    v = img.v0 + 3 * rows
    x, y = (u - D.CENTER[0]), -(v - D.CENTER[1])  # world direction, any depth
    side = x * normal[0] + y * normal[1] > 0
    depth = np.where(side, high, D.HEIGHT).astype(np.float32)
    return D.DepthImage(depth, img.u0, img.v0, 3)


@pytest.mark.parametrize("deg", [0.0, 30.0, 90.0, 135.0, 200.0, 290.0])
def test_crop_of_an_edge_turns_with_the_grasp_axis(deg):
    import jax.numpy as jnp

    t = np.deg2rad(deg)
    a = np.array([np.cos(t), np.sin(t), 0.0])
    center = np.array([[0.0, 0.0, 0.02]])
    gd = D.HEIGHT - 0.02
    high, low = (0.65 - gd) / Q.DEPTH_SCALE, (D.HEIGHT - gd) / Q.DEPTH_SCALE
    mid = Q.CROP // 2

    def crop(image, axis):
        pix, auv, g = Q.grasp_inputs(image, center, axis[None])
        return np.asarray(Q.crops(jnp.asarray(image.depth), pix, auv, g))[0]

    # the edge across the jaw axis: the far side (along +a) is high, in columns
    c = crop(_edge_image(a[:2]), a)
    assert np.allclose(c[:, mid + 2 :], high, atol=1e-5)
    assert np.allclose(c[:, : mid - 2], low, atol=1e-5)
    # the same edge with the grasp turned by 90 degrees: now it runs along rows
    b = np.array([-a[1], a[0], 0.0])  # a turned +90°: the edge is now along b's right
    c = crop(_edge_image(a[:2]), b)
    assert np.allclose(c[mid + 2 :, :], high, atol=1e-5)
    assert np.allclose(c[: mid - 2, :], low, atol=1e-5)


# -------------------------------------------------------------------- scoring


@pytest.fixture(scope="module")
def random_weights(tmp_path_factory):
    import jax

    arch = Q.Arch()
    params = Q.init_params(arch, jax.random.key(3))
    path = tmp_path_factory.mktemp("w") / "weights.npz"
    Q.save_weights(path, params, arch)
    return path


def test_weights_round_trip_without_pickle(random_weights):
    params, arch, _ = Q.load_weights(random_weights)
    assert arch == Q.Arch()
    with np.load(random_weights, allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
    assert random_weights.stat().st_size < 1_000_000
    with pytest.raises(precompute.PrecomputeError, match="no prior weights"):
        Q.load_weights(random_weights.parent / "none.npz")


def test_scorer_matches_the_training_inputs(random_weights):
    """The scoring path (crops inside one jitted call, padded image and batch)
    gives the network the same inputs as the training path (Cropper)."""
    import jax

    params, arch, _ = Q.load_weights(random_weights)
    caster = _box_caster((0.04, 0.06, 0.03), (0.0, 0.0))
    img = D.add_noise(D.downsample(D.render(caster)), np.random.default_rng(1))
    rng = np.random.default_rng(2)
    n = 700  # more than one scoring batch
    t = rng.uniform(0, 2 * np.pi, n)
    axes = np.stack([np.cos(t), np.sin(t), np.zeros(n)], axis=1)
    centers = np.stack(
        [rng.uniform(-0.02, 0.02, n), rng.uniform(-0.03, 0.03, n), np.full(n, 0.02)],
        axis=1,
    )
    q = Q.Scorer(params, arch)(img, centers, axes)
    x, z = Q.Cropper()(img, centers, axes)
    logit = np.asarray(
        jax.jit(Q.make_model(arch).apply)(params, x[..., None], z[:, None])
    )
    assert np.allclose(q, 1 / (1 + np.exp(-logit)), atol=1e-5)
    assert q.std() > 1e-4  # the crops differ, so do the scores


def _build(params, name="bar_clamp"):
    info = precompute.catalog.lookup(name)
    return build_problem(info.mesh_path, units="m", name=name, params=params)


def test_learned_q_is_deterministic_and_never_reads_p(random_weights, monkeypatch):
    monkeypatch.setattr(learned, "weights_path", lambda: random_weights)
    params = BuildParams(trials=2, grasps=60, samples=20, prior="learned")
    a, b = _build(params), _build(params)
    assert a.prior.tobytes() == b.prior.tobytes()
    assert a.meta["prior_kind"] == "learned"
    assert a.meta["prior"]["synthetic"] is False
    assert a.meta["prior"]["weights_sha256"] == Q.file_sha256(random_weights)
    v = a.valid
    assert np.all(a.prior[~v] == 0) and np.all((a.prior[v] > 0) & (a.prior[v] < 1))
    # another perturbation model (friction and yaw; the translation noise also
    # sets the height map's margin, so it would move the reservoir too): p
    # changes, the grasps do not, and q does not change by one bit
    monkeypatch.setattr(G, "SIGMA_YAW", 4 * G.SIGMA_YAW)
    monkeypatch.setattr(G, "FRICTION_MEAN", 0.3)
    c = _build(params)
    assert np.array_equal(c.valid, a.valid)
    assert c.grasp_center.tobytes() == a.grasp_center.tobytes()
    assert c.grasp_axis.tobytes() == a.grasp_axis.tobytes()
    assert not np.array_equal(c.robustness, a.robustness)
    assert c.robustness[v].mean() < a.robustness[v].mean() - 0.05
    assert c.prior.tobytes() == a.prior.tobytes()


def test_the_prior_and_its_weights_are_in_the_build_hash(random_weights, monkeypatch):
    monkeypatch.setattr(learned, "weights_path", lambda: random_weights)
    p_syn = BuildParams(prior="synthetic")
    p_learn = BuildParams(prior="learned")
    h_syn = build_hash("0" * 64, "m", "x", p_syn)
    h_learn = build_hash("0" * 64, "m", "x", p_learn)
    assert h_syn != h_learn
    other = random_weights.parent / "other" / "weights.npz"
    params, arch, _ = Q.load_weights(random_weights)
    params = {"params": {**params["params"]}}
    params["params"]["Dense_3"] = {
        "kernel": params["params"]["Dense_3"]["kernel"] * 2,
        "bias": params["params"]["Dense_3"]["bias"],
    }
    Q.save_weights(other, params, arch)
    monkeypatch.setattr(learned, "weights_path", lambda: other)
    assert build_hash("0" * 64, "m", "x", p_learn) != h_learn
    assert build_hash("0" * 64, "m", "x", p_syn) == h_syn


def test_learned_prior_without_weights_is_a_clear_error(tmp_path, monkeypatch, capsys):
    from precompute.cli import main

    monkeypatch.setattr(learned, "weights_path", lambda: tmp_path / "none.npz")
    assert learned.default_prior() == "synthetic"
    code = main(["--object", "bar_clamp", "--prior", "learned", "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert "no weights" in err and "train-prior" in err and "Traceback" not in err


# ------------------------------------------------------------------- training


def _train_prior(out: Path, jobs: str, env, cwd):
    """``python -m precompute train-prior --quick`` into ``out`` with ``jobs``
    processes."""
    args = ["train-prior", "--quick", "--quiet", "--out", str(out), "--jobs", jobs]
    return run_module("precompute", args, cwd=cwd, env=env, timeout=300)


@pytest.mark.slow  # trains a network; the shipped prior is tested by default
def test_train_prior_quick_lowers_the_validation_loss(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = tmp_path / "w"
    r = _train_prior(out, "2", env, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    h = m["history"]
    assert h["val_loss_best"] < h["val_loss_init"] - 0.01
    assert h["best_epoch"] >= 1
    assert (
        m["split_objects"]["train"]
        + m["split_objects"]["val"]
        + m["split_objects"]["test"]
        == m["config"]["objects"]
    )
    assert m["weights_sha256"] == Q.file_sha256(out / "weights.npz")
    card = (out / "MODEL_CARD.md").read_text()
    assert m["weights_sha256"] in card and "ROC AUC" in card
    Q.load_weights(out / "weights.npz")


def test_train_prior_refuses_bad_input(capsys):
    from precompute.cli import main

    assert main(["train-prior", "--objects", "3"]) == 2
    assert "--objects must be at least 10" in capsys.readouterr().err


def test_split_is_by_object_and_seeded():
    from precompute.train_prior import split_objects

    a, b = split_objects(100, 0), split_objects(100, 0)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    allv = np.concatenate([a["train"], a["val"], a["test"]])
    assert np.array_equal(np.sort(allv), np.arange(100))
    assert len(a["test"]) == len(a["val"]) == 10
    assert not np.array_equal(split_objects(100, 1)["test"], a["test"])


def test_metrics_against_known_answers():
    from precompute.train_prior import metrics

    p = np.array([0.9, 0.8, 0.1, 0.0])
    m = metrics(np.array([0.7, 0.6, 0.4, 0.3]), p)
    assert m["accuracy"] == 1.0 and m["roc_auc"] == 1.0
    m = metrics(np.array([0.3, 0.6, 0.7, 0.1]), p)
    # pairs (pos, neg): (0.3, 0.7) wrong, (0.3, 0.1) right, (0.6, 0.7) wrong,
    # (0.6, 0.1) right -> AUC 0.5; accuracy: 0.6 and 0.1 right -> 0.5
    assert m["roc_auc"] == 0.5 and m["accuracy"] == 0.5


@pytest.mark.slow
def test_train_prior_is_deterministic_whatever_the_process_count(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    shas = []
    for jobs in ("1", "2"):
        out = tmp_path / jobs
        r = _train_prior(out, jobs, env, tmp_path)
        assert r.returncode == 0, r.stderr[-2000:]
        shas.append(Q.file_sha256(out / "weights.npz"))
    assert shas[0] == shas[1]


def test_report_reliability_counts_and_auc_known_answers():
    from precompute.report import reliability_counts, roc_auc

    q = np.array([0.05, 0.07, 0.55, 0.95, 1.0])
    p = np.array([0.0, 0.2, 0.6, 1.0, 0.4])
    c = reliability_counts(q, p)
    assert c.shape == (10, 4)
    assert c[0].tolist() == pytest.approx([2, 0.12, 0.2, 0])
    assert c[5].tolist() == pytest.approx([1, 0.55, 0.6, 1])
    assert c[9].tolist() == pytest.approx([2, 1.95, 1.4, 1])  # q = 1 in the top bin
    assert c[:, 0].sum() == 5
    # positives 0.55, 0.95 against negatives 0.05, 0.07, 1.0: 4 of 6 pairs right
    assert roc_auc(q, p >= 0.5) == pytest.approx(4 / 6)
    assert np.isnan(roc_auc(q, np.zeros(5, bool)))


def test_switching_a_built_file_to_the_learned_prior_rescores_only(
    tmp_path, random_weights, monkeypatch
):
    """A file current in everything but its prior gets only q recomputed, from the
    pose's image and the stored grasps: byte-identical to a full learned build."""
    import shutil

    import precompute.build as B
    from precompute.build import read_meta

    folder = tmp_path / "meshes" / "dexnet_adv"
    folder.mkdir(parents=True)
    trimesh.creation.box((0.03, 0.05, 0.02)).export(folder / "brick.obj")
    small = {"trials": 1, "grasps": 30, "samples": 10}
    with monkeypatch.context() as m:
        # built before the weights were shipped: synthetic was the default
        m.setattr(learned, "default_prior", lambda: "synthetic")
        path = precompute.ensure(
            ["brick"],
            data_dir=tmp_path,
            progress=False,
            jobs=1,
            params=BuildParams(**small, prior="synthetic"),
        )["brick"]
    assert path == tmp_path / "problems" / "dexnet_adv" / "brick.npz"
    before = np.load(path)
    monkeypatch.setattr(learned, "weights_path", lambda: random_weights)
    learned_params = BuildParams(**small, prior="learned")
    with monkeypatch.context() as m:
        m.setattr(B, "build_problem", None)  # a full build would fail
        precompute.ensure(
            ["brick"], data_dir=tmp_path, progress=False, jobs=1, params=learned_params
        )
    after = np.load(path)
    assert np.array_equal(before["robustness"], after["robustness"])
    assert not np.array_equal(before["prior"], after["prior"])
    assert read_meta(path)["prior_kind"] == "learned"
    fresh = tmp_path / "fresh"
    shutil.copytree(tmp_path / "meshes", fresh / "meshes")
    path2 = precompute.ensure(
        ["brick"], data_dir=fresh, progress=False, jobs=1, params=learned_params
    )["brick"]
    assert path2.read_bytes() == path.read_bytes()
