"""The problem families of the regimes map have the properties they are asked for:
the p histogram of each shape (Kolmogorov-Smirnov against the declared mixture,
fixed seeds), the prior's C-index, its calibration, the concentration of λ; and the
features measure known answers on hand-made problems."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from legs_jax import families as F
from legs_jax.core.problem import Problem, _no_geometry

SMALL = dict(num_poses=4, effective_poses=2.0, num_grasps=2000, num_trials=2)


def test_deterministic_and_seed_dependent():
    a = F.make_problem(3, **SMALL)
    assert a == F.make_problem(3, **SMALL)
    assert not np.array_equal(a.robustness, F.make_problem(4, **SMALL).robustness)
    # The prior's settings do not move p: problems differ only where they are asked to.
    b = F.make_problem(3, auc=0.95, calibration="pessimistic", **SMALL)
    assert np.array_equal(a.robustness, b.robustness)


@pytest.mark.parametrize("shape", list(F.SHAPES))
@pytest.mark.parametrize("excellent", [0.0, 0.01, 0.04])
def test_p_histogram_is_the_declared_mixture(shape, excellent):
    pb = F.make_problem(11, shape=shape, excellent=excellent, **SMALL)
    p = pb.robustness.astype(np.float64).ravel()  # 16 000 grasps
    ks = stats.kstest(p, lambda x: F.mixture_cdf(x, shape, excellent))
    # float32 storage moves p by < 1e-7; a 1e-3 level for 12 fixed-seed cases.
    assert ks.pvalue > 1e-3, (shape, excellent, ks)


def test_shapes_go_from_a_hump_to_most_grasps_near_zero():
    kw = dict(SMALL, excellent=0.0)
    hump = F.make_problem(5, shape="hump", **kw).robustness.ravel()
    bimodal = F.make_problem(5, shape="bimodal", **kw).robustness.ravel()
    counts, edges = np.histogram(hump, bins=10, range=(0, 1))
    assert 0.3 <= edges[np.argmax(counts)] <= 0.5  # mode of Beta(4, 5): 0.43
    assert np.mean(hump < 0.1) < 0.01
    # Beta(0.4, 6): P(p < 0.1) = 0.84 (scipy), 16 000 draws: SE 0.003.
    expected = stats.beta.cdf(0.1, *F.SHAPES["bimodal"])
    assert abs(np.mean(bimodal < 0.1) - expected) < 0.015
    assert np.mean(bimodal >= 0.9) < 1e-3


def test_share_of_excellent_grasps():
    for w in (0.0025, 0.01, 0.04):
        pb = F.make_problem(7, shape="bimodal", excellent=w, **SMALL)
        share = np.mean(pb.robustness >= 0.8)
        expected = 1.0 - F.mixture_cdf(np.array(0.8), "bimodal", w)
        se = np.sqrt(expected * (1 - expected) / pb.robustness.size)
        assert abs(share - expected) < 4 * se + 1e-4, (w, share, expected)


@pytest.mark.parametrize("auc", [0.5, 0.7, 0.85, 0.95])
def test_prior_c_index_is_the_requested_one(auc):
    pb = F.make_problem(2, auc=auc, **SMALL)
    got = np.mean(
        [
            F.concordance(pb.robustness[t, s], pb.prior[t, s], m=600)
            for t in range(pb.num_trials)
            for s in range(pb.num_poses)
        ]
    )
    # 8 pools of 600 grasps: the estimate's SE is about 0.004.
    assert abs(got - auc) < 0.015, (auc, got)


def test_calibration_shifts_q_without_changing_its_ranking():
    kw = dict(SMALL, auc=0.85)
    cal = F.make_problem(9, calibration="calibrated", **kw)
    opt = F.make_problem(9, calibration="optimistic", **kw)
    pes = F.make_problem(9, calibration="pessimistic", **kw)
    p = cal.robustness
    # Calibrated: q has p's histogram in every pose.
    assert abs(cal.prior.mean() - p.mean()) < 0.005
    assert stats.ks_2samp(cal.prior[0, 0], p[0, 0]).pvalue > 1e-3
    assert opt.prior.mean() - p.mean() > 0.1
    # Pessimistic: near zero except at the most robust grasps.
    assert np.median(pes.prior) < 0.06 and pes.prior.max() > 0.5
    for other in (opt, pes):
        for t, s in ((0, 0), (1, 3)):
            a = stats.kendalltau(cal.prior[t, s], other.prior[t, s]).statistic
            assert a > 0.999


@pytest.mark.parametrize("neff", [1.0, 1.5, 4.0, 7.5, 8.0])
def test_landing_concentration(neff):
    lam = F.landing(8, neff)
    assert abs(lam.sum() - 1.0) < 1e-12
    assert abs(1.0 / np.sum(lam**2) - neff) < 1e-6
    assert np.all(np.diff(lam) <= 1e-15)
    pb = F.make_problem(0, num_poses=8, effective_poses=neff, num_grasps=20)
    assert abs(F.features(pb)["effective_poses"] - neff) < 1e-3
    np.testing.assert_allclose(pb.topple, np.tile(pb.landing, (8, 1)), atol=1e-7)


def test_bad_arguments_are_refused_with_a_message():
    for kw, word in (
        (dict(shape="flat"), "shape"),
        (dict(auc=0.4), "auc"),
        (dict(calibration="wild"), "calibration"),
        (dict(effective_poses=9.0), "effective_poses"),
        (dict(excellent=1.5), "excellent"),
    ):
        with pytest.raises(ValueError, match=word):
            F.make_problem(0, num_grasps=20, **kw)


def test_concordance_known_answers():
    p = np.linspace(0, 1, 50)
    assert F.concordance(p, p) == 1.0
    assert F.concordance(p, -p) == 0.0
    assert F.concordance(p, np.zeros(50)) == 0.5
    # Two of the three ordered pairs agree: (0, 1) and (0, 2); (1, 2) does not.
    assert F.concordance([0.1, 0.5, 0.9], [0.0, 0.8, 0.7]) == pytest.approx(2 / 3)
    assert np.isnan(F.concordance([0.3, 0.3], [0.1, 0.2]))


def _hand_made() -> Problem:
    """Two poses, λ = (0.75, 0.25); pose 1 has 3 of its 4 slots valid."""
    rob = np.array([[[0.9, 0.88, 0.5, 0.1], [0.4, 0.2, 0.2, 0.0]]], np.float32)
    prior = np.array([[[0.8, 0.6, 0.4, 0.2], [0.1, 0.3, 0.2, 0.0]]], np.float32)
    valid = np.array([[[True] * 4, [True, True, True, False]]])
    lam = np.array([0.75, 0.25], np.float32)
    return Problem(
        name="hand",
        landing=lam,
        topple=np.tile(lam, (2, 1)),
        robustness=rob,
        prior=prior,
        valid=valid,
        pose_valid=np.ones(2, bool),
        **_no_geometry((1, 2, 4)),
    ).validate()


def test_features_of_a_hand_made_problem():
    f = F.features(_hand_made(), horizon=100, k=2)
    # Pose 0: p* 0.9, near {0.9, 0.88}: 2 of 4; mean p 0.595. Pose 1: p* 0.4,
    # near {0.4}: 1 of 3; mean p 0.8 / 3.
    assert f["share_near"] == pytest.approx(0.75 * 0.5 + 0.25 / 3)
    assert f["count_near"] == 2.0  # λ-weighted median: pose 0 holds 0.75
    assert f["p_star"] == pytest.approx(0.75 * 0.9 + 0.25 * 0.4)
    assert f["mean_over_best"] == pytest.approx(
        0.75 * 0.595 / 0.9 + 0.25 * (0.8 / 3) / 0.4, rel=1e-6
    )
    # Pose 0: q orders all 6 pairs as p does; pose 1: pairs with different p are
    # (0.4, 0.2) twice: q 0.1 < 0.3 and 0.1 < 0.2, both wrong.
    assert f["auc"] == pytest.approx(0.75 * 1.0 + 0.25 * 0.0)
    assert f["calibration"] == pytest.approx(
        0.75 * (0.5 - 0.595) + 0.25 * (0.2 - 0.8 / 3), abs=1e-6
    )
    assert f["effective_poses"] == pytest.approx(1 / (0.75**2 + 0.25**2), rel=1e-6)
    # Attempts per active grasp: λ_s H / min(k, valid) weighted by λ_s.
    assert f["attempts_per_active"] == pytest.approx(
        0.75 * 75 / 2 + 0.25 * 25 / 2, rel=1e-6
    )
