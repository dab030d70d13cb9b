"""What every part of the benchmark shares: its settings, the methods it times,
and timing helpers (medians of repeats; wall and CPU seconds).

JAX and the modules that load it (the methods, the engine, the reference) are
imported inside the functions: JAX must start after the benchmark has set one
host device per core (:func:`legs_jax.bench.common._set_host_devices`).
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

_PROG = "python -m legs_jax.bench"
_DESCRIPTION = (
    "Measure exact Beta samples/s (legs_jax vs jax.random.beta vs NumPy), "
    "rollout steps/s of the JAX engine vs the NumPy reference, the cost of a "
    "stopping check (the paper's bound and ours), and project "
    "the wall time of the full sweep (python -m legs_jax.sweep --all)."
)


def _all_methods() -> tuple[str, ...]:
    """Every registered method (legs_jax.core.methods), in registry order (imported
    late: JAX must start after the device flags are set)."""
    from legs_jax.core import methods

    return methods.names()


def table_methods() -> tuple[str, ...]:
    """Methods of the table (their declaration's ``bench``); the others get a rate
    in the full run (for the projection) or borrow the rate of their
    ``bench_proxy``, a method with the same per-step work."""
    from legs_jax.core import methods

    return tuple(m for m in methods.names() if methods.get(m).card.bench)


def proxy() -> dict[str, str]:
    """Method -> the table's method whose rate stands in for it (``bench_proxy``)."""
    from legs_jax.core import methods

    out = {}
    for m in methods.names():
        if methods.get(m).card.bench_proxy:
            out[m] = methods.get(m).card.bench_proxy
    return out


# Dirichlet checks every this many steps for the methods the main sweep checks
# (experiments.main.CHECK_METHODS); the others run without, as in the sweep.
CHECK_EVERY = 100
# The object sets (used when the mesh catalogue is not installed).
SET_SIZES = {"dexnet_adv": 13, "egad_eval": 49}
MAX_HOST_DEVICES = 8


@dataclass(frozen=True)
class Settings:
    quick: bool
    repeats: int
    min_seconds: float  # shortest timed stretch of one sampler repeat
    sampler_rows: int
    sampler_arms: int
    poses: int
    grasps: int
    trials: int
    horizon: int
    rollouts_dense: int  # rollouts of a JAX run of a dense method
    rollouts_sparse: int  # of the other methods
    reference_horizon: int
    reference_seconds: float  # shortest timed stretch of one reference repeat
    methods: tuple[str, ...]
    numpy_all_cores: bool


def _with_table(methods: Sequence[str]) -> tuple[str, ...]:
    """The table's methods always run (the projection borrows their rates)."""
    return tuple(m for m in _all_methods() if m in methods or m in table_methods())


# Sizes of a run: (--quick, full).
_SIZES = dict(
    repeats=(2, 3),
    min_seconds=(0.2, 1.0),
    sampler_rows=(16, 64),
    sampler_arms=(2000, 2000),
    poses=(4, 8),
    grasps=(2000, 2000),
    trials=(2, 8),
    horizon=(100, 1000),
    rollouts_dense=(32, 128),
    rollouts_sparse=(256, 2048),
    reference_horizon=(100, 1000),
    reference_seconds=(0.3, 3.0),
)


def settings(quick: bool, methods: Sequence[str] | None) -> Settings:
    """A quick run times the table's methods by default, a full run all of them;
    the NumPy reference also runs on every core in a full run."""
    default = table_methods() if quick else _all_methods()
    return Settings(
        quick=quick,
        **{k: v[0 if quick else 1] for k, v in _SIZES.items()},
        methods=_with_table(methods or default),
        numpy_all_cores=not quick,
    )


def _set_host_devices() -> None:
    """One XLA host device per core (at most 8), before JAX starts."""
    flags = os.environ.get("XLA_FLAGS", "")
    n = min(os.cpu_count() or 1, MAX_HOST_DEVICES)
    if n >= 2 and "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = (
            flags + f" --xla_force_host_platform_device_count={n}"
        ).strip()


def _say(msg: str, quiet: bool) -> None:
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def _timed_rate(
    fn: Callable[[], Any], work: float, repeats: int, min_seconds: float
) -> float:
    """Median over ``repeats`` of work per second; each repeat calls ``fn`` until
    at least ``min_seconds`` have passed."""
    return statistics.median(
        _timed_calls(fn, work, min_seconds)[0] for _ in range(repeats)
    )


def _timed_calls(
    fn: Callable[[], Any], work: float, min_seconds: float
) -> tuple[float, float]:
    """(work per wall second, work per CPU second of this process) of calling
    ``fn`` until at least ``min_seconds`` have passed."""
    calls = 0
    start, cpu0 = time.perf_counter(), time.process_time()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_seconds:
            break
    used = max(time.process_time() - cpu0, 1e-9)
    return work * calls / elapsed, work * calls / used


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def _interleaved_rates(
    fns: dict[str, Callable[[], Any]], work: float, repeats: int, min_seconds: float
) -> dict[str, dict[str, float]]:
    """Work per second of each of ``fns``, timed in turns (repeat r of every one
    before repeat r + 1 of any), so that a change of machine load hits them
    alike, and in an order rotated by one from each repeat to the next, so that
    none is always the first timed after another's run (in short repeats the
    first of a turn was measured slower than the same function later in it).
    For each: the median over repeats of work per wall second and of work per
    CPU second of this process (all its threads: a per-core rate however many
    cores a program used)."""
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for fn in fns.values():
        fn()  # warm-up (compiled already)
    names = list(fns)
    for r in range(repeats):
        shift = r % len(names) if names else 0
        for name in names[shift:] + names[:shift]:
            per_s, per_cpu_s = _timed_calls(fns[name], work, min_seconds)
            wall[name].append(per_s)
            cpu[name].append(per_cpu_s)
    return {
        k: {"per_s": statistics.median(wall[k]), "per_cpu_s": statistics.median(cpu[k])}
        for k in fns
    }
