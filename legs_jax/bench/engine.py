"""Rollout steps per second: the JAX engine against the NumPy reference of the
same method with the same settings.

JAX and the modules that load it (the methods, the engine, the reference) are
imported inside the functions: JAX must start after the benchmark has set one
host device per core (:func:`legs_jax.bench.common._set_host_devices`).
"""

from __future__ import annotations

import math
import os
import statistics
import time

from legs_jax.bench.common import CHECK_EVERY, Settings, _timed_rate


def _problem(cfg: Settings, poses: int | None = None):
    from legs_jax import synthetic

    return synthetic.make_problem(
        0,
        num_poses=poses or cfg.poses,
        num_grasps=cfg.grasps,
        num_trials=cfg.trials,
        name="bench",
    )


def _checked(method: str) -> bool:
    import experiments

    return method in experiments.get("main").CHECK_METHODS


def bench_jax_engine(method: str, cfg: Settings, problem) -> dict[str, float]:
    from legs_jax import runtime
    from legs_jax.core.problem import stack

    batch = stack([problem])
    from legs_jax.core import methods

    dense = methods.get(method).card.dense  # per-step work O(K): fewer rollouts
    total = cfg.rollouts_dense if dense else cfg.rollouts_sparse
    per_trial = max(1, total // cfg.trials)
    steps = cfg.trials * per_trial * cfg.horizon

    def once():
        runtime.run(
            batch,
            method,
            object_ids=[0],
            num_rollouts=per_trial,
            horizon=cfg.horizon,
            check_every=CHECK_EVERY if _checked(method) else None,
            progress=False,
        )

    start = time.perf_counter()
    once()
    first = time.perf_counter() - start
    rate = _timed_rate(once, steps, cfg.repeats, 0.0)
    return {
        "jax": rate,
        "compile_s": round(max(first - steps / rate, 0.0), 2),
        "rollouts": cfg.trials * per_trial,
        "horizon": cfg.horizon,
    }


def _reference_rollouts(args) -> int:
    """Worker: run ``count`` reference rollouts; returns the steps done."""
    problem, method, horizon, trial, first, count = args
    from legs_jax.core import reference

    reference.run(
        problem,
        method,
        trials=[trial],
        num_rollouts=count,
        horizon=horizon,
        seed=first,
        check_every=CHECK_EVERY if _checked(method) else horizon + 1,
    )
    return count * horizon


def bench_reference(method: str, cfg: Settings, problem) -> float:
    """NumPy reference steps per second, one process (one rollout at a time)."""
    from legs_jax.core import reference

    horizon = cfg.reference_horizon
    rates = []
    for rep in range(cfg.repeats):
        steps = 0
        start = time.perf_counter()
        while True:
            reference.run(
                problem,
                method,
                trials=[rep % cfg.trials],
                num_rollouts=1,
                horizon=horizon,
                seed=steps,
                check_every=CHECK_EVERY if _checked(method) else horizon + 1,
            )
            steps += horizon
            elapsed = time.perf_counter() - start
            if elapsed >= cfg.reference_seconds:
                break
        rates.append(steps / elapsed)
    return statistics.median(rates)


def bench_reference_all_cores(method: str, cfg: Settings, problem, one: float) -> float:
    """NumPy reference with one worker process per core, rollouts in parallel."""
    import multiprocessing as mp

    workers = os.cpu_count() or 1
    horizon = cfg.reference_horizon
    # Enough rollouts for each worker to run about reference_seconds.
    per_worker = max(1, math.ceil(cfg.reference_seconds * one / horizon))
    jobs = [
        (problem, method, horizon, i % cfg.trials, i, per_worker)
        for i in range(workers)
    ]
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers) as pool:
        pool.map(_reference_rollouts, [(problem, method, 10, 0, 0, 1)] * workers)
        rates = []
        for _ in range(cfg.repeats):
            start = time.perf_counter()
            steps = sum(pool.map(_reference_rollouts, jobs))
            rates.append(steps / (time.perf_counter() - start))
    return statistics.median(rates)
