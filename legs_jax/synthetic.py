"""Seeded synthetic problems shaped like adversarial objects.

Tests of every later piece run on these, and users can try the methods without
meshes. The ground truth follows the paper's Fig. 3 histograms: most grasps near 0,
a few good ones, and some poses with no good grasp at all. The prior is an
imperfect estimate of the truth with controllable noise, as GQ-CNN is.

Dimension letters: T trials, P poses, K grasps per pose.
"""

from __future__ import annotations

import numpy as np

from legs_jax.core.problem import Problem

__all__ = ["make_problem"]


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-4, 1 - 1e-4)
    return np.log(p) - np.log1p(-p)


def make_problem(
    seed: int = 0,
    num_poses: int = 4,
    num_grasps: int = 200,
    num_trials: int = 2,
    *,
    good_fraction: float = 0.02,
    bad_pose_fraction: float = 0.25,
    prior_noise: float = 1.0,
    prior_bias: float = 0.0,
    topple_stay: float = 0.7,
    invalid_fraction: float = 0.0,
    name: str | None = None,
) -> Problem:
    """Build a random problem, deterministic in ``seed``.

    Args:
      seed: random seed; the same arguments give an identical problem.
      num_poses, num_grasps, num_trials: P, K, T.
      good_fraction: expected fraction of grasps drawn from the "good" component
        (p ~ Beta(8, 2)); the rest are mostly failures (p ~ Beta(0.4, 6)).
      bad_pose_fraction: expected fraction of poses with no good grasp (all of
        their grasps have p < 0.3). Pose 0 always has a good grasp, so the
        problem is never hopeless.
      prior_noise: standard deviation of the Gaussian noise added to logit(p)
        to make the prior q; 0 gives a perfect prior (q = p up to clipping).
      prior_bias: added to logit(q) (positive: optimistic prior).
      topple_stay: probability that a failed grasp leaves the object in its pose;
        the rest is spread at random over the other poses.
      invalid_fraction: fraction of grasp slots of each pose beyond 10 that are
        empty (padding), to exercise masks.
      name: the problem's name (default ``synthetic-<seed>``).
    """
    if num_poses < 1 or num_grasps < 1 or num_trials < 1:
        raise ValueError("num_poses, num_grasps and num_trials must be >= 1")
    if not 0.0 <= invalid_fraction < 1.0:
        raise ValueError("invalid_fraction must lie in [0, 1)")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1E65]))
    P, K, T = num_poses, num_grasps, num_trials

    landing = rng.dirichlet(np.full(P, 2.0))
    landing = landing / landing.sum()

    topple = np.zeros((P, P))
    for s in range(P):
        others = rng.dirichlet(np.ones(P - 1)) if P > 1 else np.zeros(0)
        topple[s, np.arange(P) != s] = (1.0 - topple_stay) * others
        topple[s, s] = topple_stay if P > 1 else 1.0
    topple /= topple.sum(axis=1, keepdims=True)

    bad_pose = rng.random(P) < bad_pose_fraction
    bad_pose[0] = False
    good = rng.random((T, P, K)) < good_fraction
    good[:, :, 0] |= ~good.any(axis=2)  # at least one good grasp per (trial, pose)
    p_good = rng.beta(8.0, 2.0, size=(T, P, K))
    p_bad = rng.beta(0.4, 6.0, size=(T, P, K))
    robustness = np.where(good, p_good, p_bad)
    robustness = np.where(bad_pose[None, :, None], 0.3 * robustness, robustness)
    # Shuffle so that the guaranteed good slot is not always index 0.
    perm = rng.permuted(np.broadcast_to(np.arange(K), (T, P, K)), axis=2)
    robustness = np.take_along_axis(robustness, perm, axis=2)

    noise = rng.normal(0.0, 1.0, size=(T, P, K))
    prior = _sigmoid(_logit(robustness) + prior_bias + prior_noise * noise)

    valid = np.ones((T, P, K), bool)
    if invalid_fraction > 0 and K > 10:
        n_empty = int(round(invalid_fraction * (K - 10)))
        valid[:, :, K - n_empty :] = False
    robustness = np.where(valid, robustness, 0.0)
    prior = np.where(valid, prior, 0.0)

    # Simple geometry so that every consumer of grasp fields has something to draw.
    angle = rng.uniform(0.0, np.pi, size=(T, P, K))
    axis = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=-1)
    center = rng.uniform(-0.03, 0.03, size=(T, P, K, 3))
    center[..., 2] = rng.uniform(0.005, 0.03, size=(T, P, K))
    width = rng.uniform(0.01, 0.08, size=(T, P, K))
    pose_transform = np.tile(np.eye(4), (P, 1, 1))

    f32 = np.float32
    return Problem(
        name=name if name is not None else f"synthetic-{seed}",
        landing=landing.astype(f32) / landing.astype(f32).sum(dtype=f32),
        topple=(topple / topple.sum(axis=1, keepdims=True)).astype(f32),
        robustness=robustness.astype(f32),
        prior=prior.astype(f32),
        valid=valid,
        grasp_center=np.where(valid[..., None], center, 0.0).astype(f32),
        grasp_axis=np.where(valid[..., None], axis, 0.0).astype(f32),
        grasp_width=np.where(valid, width, 0.0).astype(f32),
        grasp_height=np.where(valid, center[..., 2], 0.0).astype(f32),
        pose_transform=pose_transform.astype(f32),
        pose_valid=np.ones(P, bool),
        meta={"source": "synthetic", "seed": int(seed), "prior": "synthetic"},
    ).validate()
