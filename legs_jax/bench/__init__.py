"""Speed benchmark: exact Beta sampling and rollout throughput, side by side.

The parts: :mod:`legs_jax.bench.sampler` (Beta samplers, random words, memory),
:mod:`legs_jax.bench.engine` (rollout steps against the reference),
:mod:`legs_jax.bench.checks` (what a stopping check costs, each bound alone),
:mod:`legs_jax.bench.projection` (the sweep's projected time),
:mod:`legs_jax.bench.table` (the printed table) and :mod:`legs_jax.bench.cli` (the
command line and :func:`run`); :mod:`legs_jax.bench.common` holds what they share.
"""

from __future__ import annotations

from legs_jax.bench.checks import bench_check_cost, bench_legs_checks
from legs_jax.bench.cli import build_parser, main, run
from legs_jax.bench.common import (
    CHECK_EVERY,
    MAX_HOST_DEVICES,
    SET_SIZES,
    Settings,
    proxy,
    settings,
    table_methods,
)
from legs_jax.bench.engine import (
    bench_jax_engine,
    bench_reference,
    bench_reference_all_cores,
)
from legs_jax.bench.projection import (
    count_objects,
    pose_buckets,
    projection,
    projection_by_chunk,
    sweep_plans,
)
from legs_jax.bench.sampler import (
    bench_memory,
    bench_sampler,
    bench_sampler_versions,
)
from legs_jax.bench.table import format_table

__all__ = [
    "CHECK_EVERY",
    "MAX_HOST_DEVICES",
    "SET_SIZES",
    "Settings",
    "bench_check_cost",
    "bench_jax_engine",
    "bench_legs_checks",
    "bench_memory",
    "bench_reference",
    "bench_reference_all_cores",
    "bench_sampler",
    "bench_sampler_versions",
    "count_objects",
    "build_parser",
    "format_table",
    "main",
    "pose_buckets",
    "projection",
    "projection_by_chunk",
    "proxy",
    "run",
    "settings",
    "sweep_plans",
    "table_methods",
]
