"""A stand-in for ``legs_jax.runtime.run`` used by the sweep bookkeeping tests.

It returns results of the engine's shapes whose values depend only on (seed,
object id, trial, rollout, hyperparameters), as the real engine's do, so that
chunking, resuming and merging can be tested in milliseconds. The real engine is
exercised by the integration tests in ``test_sweep.py``.
"""

from __future__ import annotations

import hashlib
from typing import NamedTuple

import numpy as np


class FakeResult(NamedTuple):
    final_gap: np.ndarray
    final_performance: np.ndarray
    successes: np.ndarray
    distinct_grasps: np.ndarray
    replacements: np.ndarray
    curve_steps: np.ndarray
    gap_curve: np.ndarray
    check_steps: np.ndarray
    check_p_lower: np.ndarray
    check_p_lower_attempted: np.ndarray
    check_true_performance: np.ndarray
    active_set: np.ndarray | None


def _grid(hparams) -> list[dict]:
    hparams = dict(hparams or {})
    g = max([len(v) for v in hparams.values() if isinstance(v, tuple | list)] or [1])
    return [
        {k: (v[i] if isinstance(v, tuple | list) else v) for k, v in hparams.items()}
        for i in range(g)
    ]


def _run_seed(seed, oid, trial, rollout, point) -> np.random.Generator:
    tag = repr(sorted(point.items())).encode()
    h = int.from_bytes(hashlib.sha256(tag).digest()[:4], "little")
    return np.random.default_rng([seed, oid, trial, rollout, h])


def fake_run(
    batch,
    method,
    *,
    object_ids,
    trials=None,
    num_rollouts=10,
    horizon=3000,
    hparams=None,
    seed=0,
    rollout_offset=0,
    record_every=10,
    check_every=100,
    stop_variant_attempted=True,
    record_active_set=False,
    devices=None,
    progress=None,
    shape_of=None,
    calls=None,
):
    grid = _grid(hparams)
    O, T, P, K = batch.robustness.shape  # noqa: E741
    trials = list(range(T)) if trials is None else list(trials)
    R = num_rollouts
    steps1 = np.arange(0, horizon + 1, record_every)
    if steps1[-1] != horizon:
        steps1 = np.append(steps1, horizon)
    if check_every and check_every <= horizon:
        steps2 = np.arange(check_every, horizon + 1, check_every)
    else:
        steps2 = np.zeros(0, np.int64)
    G, C1, C2, k = len(grid), len(steps1), len(steps2), 5
    shape = (G, O, len(trials), R)
    out = {
        n: np.zeros(shape + extra, dt)
        for n, extra, dt in [
            ("final_gap", (), np.float32),
            ("final_performance", (), np.float32),
            ("successes", (), np.int32),
            ("distinct_grasps", (), np.int32),
            ("replacements", (), np.int32),
            ("gap_curve", (C1,), np.float32),
            ("check_p_lower", (C2,), np.float32),
            ("check_p_lower_attempted", (C2,), np.float32),
            ("check_true_performance", (C2,), np.float32),
            ("active_set", (C2, P, k), np.int32),
        ]
    }
    for g, point in enumerate(grid):
        for o, oid in enumerate(object_ids):
            for t, trial in enumerate(trials):
                for r in range(R):
                    rng = _run_seed(seed, oid, trial, r + rollout_offset, point)
                    curve = np.sort(rng.random(C1).astype(np.float32))[::-1]
                    i = (g, o, t, r)
                    out["gap_curve"][i] = curve
                    out["final_gap"][i] = curve[-1]
                    out["final_performance"][i] = 1 - curve[-1]
                    out["successes"][i] = rng.integers(0, horizon + 1)
                    out["distinct_grasps"][i] = rng.integers(1, 50)
                    out["replacements"][i] = rng.integers(0, 20)
                    out["check_p_lower"][i] = rng.random(C2)
                    out["check_p_lower_attempted"][i] = rng.random(C2)
                    out["check_true_performance"][i] = rng.random(C2)
                    a = rng.integers(-1, K, size=(C2, P, k))
                    a[:, ~batch.pose_valid[o]] = -1
                    out["active_set"][i] = a
    if callable(progress):
        total = G * O * len(trials) * R
        progress(total // 2)
        progress(total)
    if calls is not None:
        calls.append((method, tuple(object_ids), tuple(trials)))
    return FakeResult(
        curve_steps=steps1,
        check_steps=steps2,
        **{
            n: (v if n != "active_set" or record_active_set else None)
            for n, v in out.items()
        },
    )
