"""The prior q: a synthetic stand-in for GQ-CNN. Synthetic, not learned.

GQ-CNN cannot be run here, so q is made from the ground truth p plus seeded noise:

    q = sigmoid(SLOPE · (p − 0.5 + NOISE · ε)),   ε ~ N(0, 1) per grasp.

NOISE (in units of p) is the imprecision of the stand-in network. It was calibrated
with ``python -m precompute calibrate`` on the Dex-Net set so that the prior-only
rows land near the paper's Table I (Dex-Net greedy gap ≈ 0.56, K100 upper bound
≈ 0.08); the result is a weak prior (correlation with p about 0.3), as GQ-CNN is on
adversarial objects. SLOPE only sets the spread of q (most q between 0.1 and 0.9);
it does not change any ranking.

q is deterministic per (seed, object, trial, pose, grasp slot): the noise of a
(trial, pose) reservoir comes from its own seeded stream, one draw per slot in slot
order.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SLOPE", "NOISE", "prior_params", "prior_noise", "prior_from_noise"]

SLOPE = 1.5
NOISE = 1.0


def prior_params(noise: float | None = None) -> dict:
    """The prior's constants (``noise``: NOISE unless given), as recorded."""
    noise = NOISE if noise is None else noise
    return {
        "model": "sigmoid(slope * (p - 0.5 + noise * N(0, 1)))",
        "slope": SLOPE,
        "noise": float(noise),
        "calibrated_on": "dexnet_adv prior-only rows (paper: 0.56 / 0.08)",
        "synthetic": True,
    }


def prior_noise(rng: np.random.Generator, k: int) -> np.ndarray:
    """ε [K] of one reservoir, one standard normal per slot."""
    return rng.standard_normal(k)


def prior_from_noise(
    p: np.ndarray, eps: np.ndarray, noise: float | None = None
) -> np.ndarray:
    """q in (0, 1) from p and the reservoir's noise draws (same shapes); ``noise``:
    NOISE unless given."""
    noise = NOISE if noise is None else noise
    z = SLOPE * (np.asarray(p, np.float64) - 0.5 + noise * np.asarray(eps))
    return 1.0 / (1.0 + np.exp(-z))
