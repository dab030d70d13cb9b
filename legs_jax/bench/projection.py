"""The projected wall time of ``python -m legs_jax.sweep --all`` from measured
rates: by experiment, or chunk by chunk as the sweep runs them.

JAX and the modules that load it (the methods, the engine, the reference) are
imported inside the functions: JAX must start after the benchmark has set one
host device per core (:func:`legs_jax.bench.common._set_host_devices`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from legs_jax.bench.common import SET_SIZES, proxy


def count_objects(names: Sequence[str]) -> int:
    try:
        from precompute import catalog

        sizes = {s: len(catalog.objects(s)) for s in SET_SIZES}
    except Exception:  # the catalogue is optional here
        sizes = dict(SET_SIZES)
    return sum(sizes.get(n, 1) for n in names)


def _projected(
    how: str, seconds: float, per_exp: dict[str, float], steps: float
) -> dict[str, Any]:
    """A projection's result: total and per-experiment minutes, rollout-steps."""
    return {
        "projection": how,
        "projected_all_minutes": round(seconds / 60.0, 2),
        "projected_minutes_per_experiment": per_exp,
        "all_rollout_steps": steps,
    }


def projection(rates: dict[str, float]) -> dict[str, Any]:
    """Minutes of ``--all`` from rollout-steps per second of each method, every
    object charged at the benchmark's pose count (the projection without the
    problem files: :func:`projection_by_chunk` is the one used with them).

    Work of an arm = objects x trials x rollouts x horizon x grid points, charged
    at the measured rate of its method (with the Dirichlet checks where the main
    sweep records them, as the table measures it). Compilation and precompute are
    not included.
    """
    import experiments

    proxies = proxy()
    per_exp = {}
    steps_total = 0.0
    seconds = 0.0
    for name in experiments.EXPERIMENTS:
        mod = experiments.get(name)
        n_obj = count_objects(mod.OBJECTS)
        exp_s = 0.0
        for method, _variant, hp in mod.ARMS:
            grid = max([len(v) for v in hp.values() if isinstance(v, tuple)] or [1])
            steps = n_obj * mod.TRIALS * mod.ROLLOUTS * mod.HORIZON * grid
            rate = rates.get(method) or rates[proxies[method]]
            steps_total += steps
            exp_s += steps / rate
        per_exp[name] = round(exp_s / 60.0, 2)
        seconds += exp_s
    return _projected(
        "by experiment, every object at the benchmark's pose count",
        seconds, per_exp, steps_total,
    )  # fmt: skip


def sweep_plans() -> tuple[list | None, str | None]:
    """The plans of ``--all`` (chunks, pose buckets, padding), or None and the
    reason when they cannot be made here (problem files missing)."""
    try:
        from legs_jax.sweep import shapes

        return shapes.plan_all(), None
    except Exception as e:  # noqa: BLE001 - the projection falls back
        return None, str(e).splitlines()[0] if str(e) else type(e).__name__


def pose_buckets(plans: Sequence[Any]) -> tuple[int, ...]:
    """The pose counts the sweep's chunks are padded to."""
    return tuple(sorted({c.num_poses for plan in plans for c in plan.chunks}))


def projection_by_chunk(
    rates_by_poses: dict[int, dict[str, float]], plans: Sequence[Any], n_dev: int
) -> dict[str, Any]:
    """Minutes of ``--all`` chunk by chunk, as the sweep runs them: each chunk's
    rollouts as the engine runs them (mini-batch padding included) times the
    horizon, at its method's rate for the chunk's pose bucket (``rates_by_poses[P]``;
    a bucket not measured takes the nearest measured one, a method not measured
    its ``bench_proxy``). A chunk whose rollouts an earlier experiment already
    made is copied by the sweep, not run, and costs nothing here. Compilation,
    loading and writing are not included."""
    from legs_jax.sweep import shapes
    from legs_jax.sweep.store import donor_keys

    proxies = proxy()
    measured = sorted(rates_by_poses)

    def rate(method: str, poses: int) -> float:
        p = min(measured, key=lambda m: (abs(m - poses), m))
        got = rates_by_poses[p]
        return got.get(method) or got[proxies[method]]

    made: set = set()
    per_exp: dict[str, float] = {}
    steps_total = seconds = 0.0
    for plan in plans:
        exp_s = 0.0
        new: set = set()
        for c in plan.chunks:
            keys = donor_keys(plan, c)
            if keys is not None and set(keys) <= made:
                continue  # copied from an earlier experiment
            new |= set(keys or ())
            for key, _rows, run in shapes._chunk_programs(plan, c, n_dev):
                steps = run * plan.horizon
                steps_total += steps
                exp_s += steps / rate(key[0], c.num_poses)
        made |= new
        per_exp[plan.name] = round(exp_s / 60.0, 2)
        seconds += exp_s
    return _projected(
        "chunk by chunk, at each pose bucket's rates, copies free",
        seconds, per_exp, steps_total,
    )  # fmt: skip
