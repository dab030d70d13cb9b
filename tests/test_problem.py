"""The problem container: round trip, determinism, validation messages, stacking."""

from __future__ import annotations

import dataclasses
import filecmp
import zipfile
from pathlib import Path

import numpy as np
import pytest

from legs_jax.core import problem as pm
from legs_jax.synthetic import make_problem


@pytest.fixture
def prob() -> pm.Problem:
    return make_problem(seed=3, num_poses=4, num_grasps=50, num_trials=2)


def test_round_trip_identical(tmp_path: Path, prob: pm.Problem) -> None:
    path = pm.save(prob, tmp_path / "obj.npz")
    back = pm.load(path)
    assert back == prob
    for f in dataclasses.fields(pm.Problem):
        a, b = getattr(prob, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(a, b)
    assert back.name == prob.name and back.meta == prob.meta


def test_save_is_byte_identical(tmp_path: Path, prob: pm.Problem) -> None:
    a = pm.save(prob, tmp_path / "a.npz")
    b = pm.save(
        make_problem(seed=3, num_poses=4, num_grasps=50, num_trials=2),
        tmp_path / "b.npz",
    )
    assert filecmp.cmp(a, b, shallow=False)
    c = pm.save(
        make_problem(seed=4, num_poses=4, num_grasps=50, num_trials=2),
        tmp_path / "c.npz",
    )
    assert not filecmp.cmp(a, c, shallow=False)


def test_file_without_pose_valid_loads(tmp_path: Path, prob: pm.Problem) -> None:
    arrays = {
        f.name: getattr(prob, f.name)
        for f in dataclasses.fields(pm.Problem)
        if isinstance(getattr(prob, f.name), np.ndarray) and f.name != "pose_valid"
    }
    path = tmp_path / "plain.npz"
    np.savez(path, **arrays)
    back = pm.load(path)
    assert back.name == "plain"
    assert back.pose_valid.all() and back.pose_valid.shape == (prob.num_poses,)


def _write_modified(tmp_path: Path, prob: pm.Problem, **changes) -> Path:
    """Write a problem file with some arrays replaced (None removes the array)."""
    arrays = {
        f.name: getattr(prob, f.name)
        for f in dataclasses.fields(pm.Problem)
        if isinstance(getattr(prob, f.name), np.ndarray)
    }
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    path = tmp_path / "bad_object.npz"
    np.savez(path, **arrays)
    return path


def _bad_cases(prob: pm.Problem) -> dict[str, tuple[str, dict]]:
    rob = prob.robustness.copy()
    rob_nan = rob.copy()
    rob_nan[0, 1, 2] = np.nan
    rob_big = rob.copy()
    rob_big[1, 0, 0] = 1.5
    prior_neg = prob.prior.copy()
    prior_neg[0, 0, 3] = -0.1
    topple_bad = prob.topple.copy()
    topple_bad[2, 0] += 0.3
    return {
        "missing": ("prior", {"prior": None}),
        "missing_valid": ("valid", {"valid": None}),
        "wrong_rank": ("robustness", {"robustness": rob[0]}),
        "inconsistent_shape": ("prior", {"prior": prob.prior[:, :, :10]}),
        "landing_sum": ("landing", {"landing": prob.landing * 0.5}),
        "topple_rows": ("topple", {"topple": topple_bad}),
        "robustness_range": ("robustness", {"robustness": rob_big}),
        "prior_range": ("prior", {"prior": prior_neg}),
        "nan": ("robustness", {"robustness": rob_nan}),
        "valid_dtype": ("valid", {"valid": prob.valid.astype(np.float32)}),
        "geometry_shape": ("grasp_axis", {"grasp_axis": prob.grasp_axis[..., :2]}),
        "pose_transform_shape": ("pose_transform", {"pose_transform": np.eye(4)}),
    }


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "missing_valid",
        "wrong_rank",
        "inconsistent_shape",
        "landing_sum",
        "topple_rows",
        "robustness_range",
        "prior_range",
        "nan",
        "valid_dtype",
        "geometry_shape",
        "pose_transform_shape",
    ],
)
def test_load_refuses_bad_field(tmp_path: Path, prob: pm.Problem, case: str) -> None:
    field, changes = _bad_cases(prob)[case]
    path = _write_modified(tmp_path, prob, **changes)
    with pytest.raises(pm.ProblemFileError) as info:
        pm.load(path)
    message = str(info.value)
    assert str(path) in message, message
    assert f"'{field}'" in message, message
    assert info.value.field == field


def test_load_refuses_truncated_file(tmp_path: Path, prob: pm.Problem) -> None:
    path = pm.save(prob, tmp_path / "whole.npz")
    data = path.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(pm.ProblemFileError) as info:
        pm.load(cut)
    assert str(cut) in str(info.value) and info.value.field == "<file>"


def test_load_refuses_corrupt_member(tmp_path: Path, prob: pm.Problem) -> None:
    path = tmp_path / "corrupt.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("landing.npy", b"\x93NUMPY garbage")
    with pytest.raises(pm.ProblemFileError) as info:
        pm.load(path)
    assert str(path) in str(info.value) and info.value.field == "landing"


@pytest.mark.parametrize("content", [b"", b"hello, not an archive", None])
def test_load_refuses_non_npz(tmp_path: Path, content: bytes | None) -> None:
    path = tmp_path / "thing.npz"
    if content is None:
        np.save(tmp_path / "thing.npy", np.zeros(3))
        path = tmp_path / "thing.npy"
    else:
        path.write_bytes(content)
    with pytest.raises(pm.ProblemFileError) as info:
        pm.load(path)
    assert str(path) in str(info.value) and info.value.field == "<file>"


def test_load_missing_file(tmp_path: Path) -> None:
    with pytest.raises(pm.ProblemFileError, match="no such file"):
        pm.load(tmp_path / "nope.npz")


def test_save_refuses_invalid_problem(tmp_path: Path, prob: pm.Problem) -> None:
    bad = dataclasses.replace(prob, landing=prob.landing * 2)
    with pytest.raises(pm.ProblemFileError, match="landing"):
        pm.save(bad, tmp_path / "bad.npz")
    assert not list(tmp_path.iterdir()), "a refused save must leave nothing behind"


def test_p_star_is_max_over_valid(prob: pm.Problem) -> None:
    masked = make_problem(
        seed=5, num_poses=3, num_grasps=40, num_trials=2, invalid_fraction=0.5
    )
    expected = np.array(
        [
            [masked.robustness[t, s][masked.valid[t, s]].max() for s in range(3)]
            for t in range(2)
        ]
    )
    np.testing.assert_array_equal(masked.p_star(), expected)


def test_stack_pads_and_masks() -> None:
    a = make_problem(seed=1, num_poses=2, num_grasps=30, num_trials=3)
    b = make_problem(seed=2, num_poses=5, num_grasps=20, num_trials=2)
    batch = pm.stack([a, b])
    assert batch.shape == (2, 2, 5, 30)
    assert batch.names == (a.name, b.name)
    # Real parts copied, padding masked and inert.
    np.testing.assert_array_equal(batch.robustness[0, :, :2, :], a.robustness[:2])
    np.testing.assert_array_equal(batch.prior[1, :, :, :20], b.prior)
    assert not batch.valid[0, :, 2:, :].any() and not batch.valid[1, :, :, 20:].any()
    assert (batch.robustness[~batch.valid] == 0).all()
    np.testing.assert_array_equal(batch.pose_valid[0], [1, 1, 0, 0, 0])
    assert batch.landing[0, 2:].sum() == 0
    np.testing.assert_allclose(batch.landing.sum(axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(batch.topple.sum(axis=2), 1.0, atol=1e-6)
    np.testing.assert_array_equal(batch.topple[0, 2:, 2:], np.eye(3))


def test_stack_refuses_too_few_trials() -> None:
    a = make_problem(seed=1, num_poses=2, num_grasps=10, num_trials=1)
    with pytest.raises(ValueError, match="1 trials, 2 were asked"):
        pm.stack([a], num_trials=2)


def test_peek_reads_the_header_without_the_arrays(tmp_path: Path) -> None:
    pb = make_problem(3, num_poses=5, num_grasps=70, num_trials=2, name="peeked")
    pb = dataclasses.replace(pb, meta={**pb.meta, "set": "custom", "object_id": 7})
    path = pm.save(pb, tmp_path / "p.npz")
    head = pm.peek(path)
    assert head["name"] == "peeked" and head["meta"] == pm.load(path).meta
    assert head["shapes"] == {"landing": (5,), "robustness": (2, 5, 70)}
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(pm.ProblemFileError, match=r"bad\.npz: field '<file>'"):
        pm.peek(tmp_path / "bad.npz")


def test_geometry_is_optional(tmp_path: Path, prob: pm.Problem) -> None:
    """An abstract bandit problem (no grasp or pose geometry) loads and runs;
    part of the geometry alone is refused."""
    bandit = ("landing", "topple", "robustness", "prior", "valid", "pose_valid")
    np.savez(tmp_path / "bandit.npz", **{f: getattr(prob, f) for f in bandit})
    pb = pm.load(tmp_path / "bandit.npz")
    assert pb.meta["geometry"] is False
    np.testing.assert_array_equal(pb.robustness, prob.robustness)
    assert not pb.grasp_center.any() and (pb.pose_transform == np.eye(4)).all()
    assert pm.stack([pb]).shape == pm.stack([prob]).shape
    partial = {f: getattr(prob, f) for f in (*bandit, "grasp_center")}
    np.savez(tmp_path / "partial.npz", **partial)
    with pytest.raises(pm.ProblemFileError, match="grasp_axis.*geometry or none"):
        pm.load(tmp_path / "partial.npz")


# ------------------------------------------------------ files without a header
def _bare_arrays(prob: pm.Problem) -> dict[str, np.ndarray]:
    """Only the arrays the format requires (no meta_json, no geometry)."""
    return {f: getattr(prob, f) for f in pm._REQUIRED}


def test_peek_of_a_file_without_header_gives_an_empty_meta(
    tmp_path: Path, prob: pm.Problem
) -> None:
    path = tmp_path / "abstract.npz"
    np.savez(path, **_bare_arrays(prob))
    head = pm.peek(path)
    assert head["name"] == "abstract" and head["meta"] == {}
    assert head["shapes"]["robustness"] == prob.robustness.shape
    assert pm.load(path).meta == {"geometry": False}


def test_peek_refuses_a_file_without_landing_naming_file_and_field(
    tmp_path: Path, prob: pm.Problem
) -> None:
    arrays = _bare_arrays(prob)
    del arrays["landing"]
    path = tmp_path / "broken.npz"
    np.savez(path, **arrays)
    with pytest.raises(pm.ProblemFileError, match=r"broken\.npz: field 'landing'"):
        pm.peek(path)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(pm.ProblemFileError, match=r"junk\.npz: field '<file>'"):
        pm.peek(tmp_path / "junk.npz")


# ------------------------------------------------------------ compact encoding
def _counted(prob: pm.Problem, samples: int = 50) -> pm.Problem:
    """``prob`` with every p a count of ``samples`` executions (as a build's)."""
    rng = np.random.default_rng(0)
    count = rng.binomial(samples, prob.robustness.astype(np.float64))
    rob = (count / samples).astype(np.float32)
    return dataclasses.replace(prob, robustness=np.where(prob.valid, rob, 0.0))


def test_compact_round_trip_is_exact_but_for_the_quantised_prior(
    tmp_path: Path, prob: pm.Problem
) -> None:
    prob = _counted(prob)
    path = pm.save_compact(prob, tmp_path / "c.npz", samples=50, geometry_trials=1)
    back = pm.load(path)
    for f in ("landing", "topple", "robustness", "valid", "pose_valid"):
        a, b = getattr(prob, f), getattr(back, f)
        assert a.dtype == b.dtype and np.array_equal(a, b), f
    np.testing.assert_array_equal(back.pose_transform, prob.pose_transform)
    # q: 16-bit levels, within half a level of the original
    assert back.prior.dtype == np.float32
    assert np.abs(back.prior - prob.prior).max() <= 0.5 / 65535 + 1e-7
    np.testing.assert_array_equal(
        back.prior * np.float32(65535), np.rint(back.prior * np.float32(65535))
    )
    # the geometry of trial 0 is kept, later trials load as zeros
    np.testing.assert_array_equal(back.grasp_center[0], prob.grasp_center[0])
    assert not back.grasp_center[1:].any()
    assert back.meta["geometry_trials"] == 1
    # a second save is byte-identical, and the header is peekable
    again = pm.save_compact(prob, tmp_path / "d.npz", samples=50, geometry_trials=1)
    assert filecmp.cmp(path, again, shallow=False)
    assert pm.peek(path)["shapes"]["robustness"] == prob.robustness.shape


def test_compact_refuses_p_that_is_not_a_count(
    tmp_path: Path, prob: pm.Problem
) -> None:
    with pytest.raises(pm.ProblemFileError, match="robustness"):
        pm.save_compact(prob, tmp_path / "c.npz", samples=50)


def test_array_digests_name_the_array_that_differs(prob: pm.Problem) -> None:
    a = pm.array_digests(prob)
    rob = prob.robustness.copy()
    rob[0, 0, 0] = np.nextafter(rob[0, 0, 0], np.float32(2))
    b = pm.array_digests(dataclasses.replace(prob, robustness=rob))
    assert [k for k in a if a[k] != b[k]] == ["robustness"]


def test_unlearnable_poses_names_dead_and_trapped_poses():
    import dataclasses

    from legs_jax import synthetic
    from legs_jax.core.problem import describe_unlearnable, unlearnable_poses

    pb = synthetic.make_problem(seed=0, num_poses=3, num_grasps=20, num_trials=2)
    assert unlearnable_poses(pb) == []
    topple = pb.topple.copy()
    topple[2] = 0.0
    topple[2, 2] = 1.0  # pose 2: a failure never moves the object
    # ... which alone is no defect: a success leaves the pose
    assert unlearnable_poses(dataclasses.replace(pb, topple=topple)) == []
    valid = pb.valid.copy()
    valid[1, 1] = False  # pose 1: no grasp in trial 1 only
    flags = unlearnable_poses(dataclasses.replace(pb, valid=valid, topple=topple))
    assert [f["pose"] for f in flags] == [1]
    assert flags[0]["trials_without_success"] == 1 and flags[0]["num_trials"] == 2
    assert not flags[0]["cannot_leave"] and flags[0]["trapped_trials"] == 0
    (line,) = describe_unlearnable(flags)
    assert "pose 1" in line and "1 of 2" in line and "stuck" not in line
    # p = 0 everywhere counts like no valid grasp; with topple[s, s] = 1 it traps
    rob = pb.robustness.copy()
    rob[:, 2] = 0.0
    flags = unlearnable_poses(dataclasses.replace(pb, robustness=rob, topple=topple))
    assert flags == [
        {
            "pose": 2,
            "landing": pytest.approx(float(pb.landing[2])),
            "trials_without_success": 2,
            "num_trials": 2,
            "cannot_leave": True,
            "trapped_trials": 2,
        }
    ]
    (line,) = describe_unlearnable(flags)
    assert "pose 2" in line and "stuck" in line and "2 of 2" in line
