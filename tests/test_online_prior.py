"""The online session scores new poses with the learned prior, from its own image.

The learned prior of the problem files sees a rendered, noisy image from the
camera of ``precompute.depth``; the session sees the simulated robot's camera
(another resolution, the object off-centre and turned). Scored online, the
reservoir grasps of a shipped problem must rank as the problem's own q ranks
them, and separate good grasps from bad as well as it does.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.stats import rankdata, spearmanr

from legs_jax.core import problem as problem_mod
from legs_jax.online import Intrinsics, Session, StateError, cli
from legs_jax.online import sampler as S
from legs_jax.online.robot import SimRobot, World
from precompute import learned, problemset

pytestmark = pytest.mark.skipif(
    not learned.available(), reason="the learned prior's weights are not shipped"
)

HALF = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)


@pytest.fixture(scope="module")
def clamp():
    pb = problem_mod.load(problemset.paths(["bar_clamp"])["bar_clamp"])
    return pb, World.from_problem(pb)


def _auc(score, label) -> float:
    r = rankdata(score)
    n1 = int(label.sum())
    n0 = len(label) - n1
    return float((r[label].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def _reservoir_in_view(pb, world, pose, seed, intrinsics=None):
    """The problem's trial-0 reservoir of ``pose`` placed on the table by a
    simulated robot, its depth image and the grasps in the table frame."""
    kw = {} if intrinsics is None else {"intrinsics": intrinsics}
    robot = SimRobot(world, np.random.default_rng(seed), **kw)
    robot.place(pose)
    depth = robot.render()
    s = np.flatnonzero(pb.pose_valid)[pose]
    v = pb.valid[0, s]
    R, t = robot.placement[:3, :3], robot.placement[:3, 3]
    c = pb.grasp_center[0, s][v].astype(np.float64)
    a = pb.grasp_axis[0, s][v].astype(np.float64)
    g = S.Grasps(c @ R.T + t, a @ R.T, pb.grasp_width[0, s][v], np.zeros(len(c)))
    view = S.View(depth, robot.intrinsics, robot.camera_pose)
    return g, view, pb.prior[0, s][v], pb.robustness[0, s][v]


@pytest.mark.parametrize("intrinsics", [None, HALF], ids=["sensor", "half-res"])
def test_online_learned_prior_ranks_grasps_as_the_problem_files_do(clamp, intrinsics):
    pb, world = clamp
    g, view, q_problem, p = _reservoir_in_view(
        pb, world, 1, seed=5, intrinsics=intrinsics
    )
    q = S.learned_prior(g, view)
    assert q.shape == q_problem.shape and np.all((q > 0) & (q < 1))
    # The two images differ by their noise, the camera and the resampling, so q
    # is not equal; measured 0.96 (sensor camera), the tolerance leaves room.
    assert spearmanr(q, q_problem)[0] > 0.85
    assert np.mean(np.abs(q - q_problem)) < 0.1
    good = p > 0.5
    assert 0.2 < good.mean() < 0.8
    assert _auc(q, good) > _auc(q_problem, good) - 0.05
    # the stand-in knows far less: nothing here, since these grasps have no
    # measured edge alignment; the learned prior is far from constant
    assert np.std(q) > 0.1


def test_a_session_scores_a_new_pose_with_the_learned_prior(tmp_path, clamp):
    pb, world = clamp
    robot = SimRobot(world, np.random.default_rng(2), intrinsics=HALF)
    robot.place(1)
    depth = robot.render()
    with Session.create(tmp_path / "s", "legs", reservoir_size=300) as ses:
        obs = ses.observe(depth, HALF.to_dict())
        assert obs["new"] and obs["prior"] == "learned"
        record = ses.store.records[-1]
        assert record["prior"] == "learned"
        arrays = ses.store.read_pose(record["file"], record["sha256"])
    # what the pose file holds is the learned prior of its grasps in this image:
    # the same sampler draws (seeded by the session seed and the pose) scored anew
    rng = np.random.default_rng([0, 0, 1])
    g = S.sample_grasps(
        np.where(np.isfinite(depth) & (depth > 0), depth, np.nan),
        HALF,
        ses.camera_pose,
        300,
        rng,
    )
    q = S.learned_prior(g, S.View(depth, HALF, ses.camera_pose))
    n = len(g)
    assert n > 50 and arrays["valid"].sum() == n
    np.testing.assert_allclose(arrays["q"][:n], np.clip(q, 0, 1), atol=1e-6)
    # and it is not the stand-in's [0.3, 0.7]
    assert arrays["q"][:n].max() > 0.7 or arrays["q"][:n].min() < 0.3


def test_without_weights_the_stand_in_says_so(tmp_path, clamp, monkeypatch):
    _, world = clamp
    monkeypatch.setattr(learned, "available", lambda: False)
    robot = SimRobot(world, np.random.default_rng(2), intrinsics=HALF)
    robot.place(0)
    with Session.create(tmp_path / "s", "legs", reservoir_size=200) as ses:
        with pytest.warns(UserWarning, match="geometric stand-in"):
            obs = ses.observe(robot.render(), HALF.to_dict())
        assert obs["prior"] == "geometric"
        q = ses.store.read_pose(
            ses.store.records[-1]["file"], ses.store.records[-1]["sha256"]
        )["q"]
    v = q[q > 0]
    assert v.min() >= 0.3 and v.max() <= 0.7


def test_the_prior_is_kept_by_a_resumed_session(tmp_path, clamp, capsys):
    _, world = clamp
    folder = tmp_path / "s"
    Session.create(folder, "legs", reservoir_size=200, prior="geometric").close()
    with Session.open(folder) as ses:
        assert ses.prior is S.geometric_prior
    # a prior function of one's own must be given again to resume
    Session.create(tmp_path / "c", "legs", prior=S.geometric_prior).close()
    with Session.open(tmp_path / "c") as ses, pytest.raises(StateError, match="again"):
        _ = ses.prior
    # serve refuses another --prior for an existing session, as a JSON line
    rc = cli.main(["serve", str(folder), "--prior", "learned"])
    out = capsys.readouterr().out
    assert rc == 2 and '"ok": false' in out and "geometric prior" in out
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert S.default_prior("learned") is S.learned_prior
