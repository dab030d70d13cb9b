"""Synthetic problems: valid, deterministic, shaped like adversarial objects."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from legs_jax.synthetic import make_problem


def test_deterministic_and_seed_dependent() -> None:
    a = make_problem(seed=7, num_poses=3, num_grasps=100, num_trials=2)
    b = make_problem(seed=7, num_poses=3, num_grasps=100, num_trials=2)
    c = make_problem(seed=8, num_poses=3, num_grasps=100, num_trials=2)
    assert a == b
    assert a != c


def test_shapes_and_validity() -> None:
    p = make_problem(
        seed=0, num_poses=6, num_grasps=300, num_trials=3, invalid_fraction=0.3
    )
    assert p.robustness.shape == (3, 6, 300)
    p.validate()  # raises if anything is off
    n_valid = p.valid.sum(axis=-1)
    assert (n_valid == 300 - round(0.3 * 290)).all()


def test_adversarial_shape() -> None:
    """Most grasps near 0, a few good ones, some poses without a good grasp."""
    p = make_problem(
        seed=1, num_poses=40, num_grasps=500, num_trials=2, bad_pose_fraction=0.3
    )
    r = p.robustness[p.valid]
    assert np.median(r) < 0.1
    assert 0.005 < (r > 0.5).mean() < 0.1
    p_star = p.p_star()
    no_good = (p_star < 0.3).all(axis=0)
    assert 0.1 < no_good.mean() < 0.5
    assert not no_good[0]
    assert (p_star[:, ~no_good] > 0.3).all()


def test_prior_noise_controls_correlation() -> None:
    """Rank correlation of prior and truth falls as the noise grows."""
    rhos = []
    for noise in (0.0, 0.5, 2.0, 8.0):
        p = make_problem(
            seed=2, num_poses=5, num_grasps=400, num_trials=2, prior_noise=noise
        )
        rhos.append(stats.spearmanr(p.robustness.ravel(), p.prior.ravel()).statistic)
    assert rhos[0] > 0.99, rhos
    assert all(a > b + 0.02 for a, b in zip(rhos, rhos[1:], strict=False)), rhos
    assert rhos[-1] < 0.5, rhos


def test_rejects_bad_sizes() -> None:
    with pytest.raises(ValueError, match="num_poses"):
        make_problem(num_poses=0)
    with pytest.raises(ValueError, match="invalid_fraction"):
        make_problem(invalid_fraction=1.0)
