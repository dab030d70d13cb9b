"""The benchmark's command line, and :func:`run`, which measures everything in
one run.

JAX and the modules that load it (the methods, the engine, the reference) are
imported inside the functions: JAX must start after the benchmark has set one
host device per core (:func:`legs_jax.bench.common._set_host_devices`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from legs_jax.bench.checks import bench_check_cost, bench_legs_checks
from legs_jax.bench.common import (
    _DESCRIPTION,
    _PROG,
    CHECK_EVERY,
    Settings,
    _all_methods,
    _cpu_model,
    _load,
    _say,
    _set_host_devices,
    settings,
    table_methods,
)
from legs_jax.bench.engine import (
    _checked,
    _problem,
    bench_jax_engine,
    bench_reference,
    bench_reference_all_cores,
)
from legs_jax.bench.projection import (
    pose_buckets,
    projection,
    projection_by_chunk,
    sweep_plans,
)
from legs_jax.bench.sampler import bench_memory, bench_sampler
from legs_jax.bench.table import format_table


def run(cfg: Settings, quiet: bool = False) -> dict[str, Any]:
    import jax

    result: dict[str, Any] = {
        "quick": cfg.quick,
        "machine": {
            "cpu": _cpu_model(),
            "cores": os.cpu_count(),
            "platform": jax.default_backend(),
            "devices": [str(d) for d in jax.local_devices()],
            "jax": jax.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
            "load_average_start": _load(),
        },
    }
    result.update(bench_sampler(cfg, quiet))
    result.update(bench_memory(cfg))

    problem = _problem(cfg)
    steps: dict[str, dict[str, float]] = {}
    table = table_methods()
    jax_rates: dict[str, float] = {}
    for method in cfg.methods:
        _say(f"engine: {method} (JAX)", quiet)
        row = bench_jax_engine(method, cfg, problem)
        jax_rates[method] = row["jax"]
        if method in table:
            _say(f"engine: {method} (NumPy reference)", quiet)
            row["numpy"] = bench_reference(method, cfg, problem)
            row["ratio"] = row["jax"] / row["numpy"]
            if cfg.numpy_all_cores and (os.cpu_count() or 1) > 1:
                row["numpy_all_cores"] = bench_reference_all_cores(
                    method, cfg, problem, row["numpy"]
                )
                row["ratio_all_cores"] = row["jax"] / row["numpy_all_cores"]
        steps[method] = row
    result["steps_per_s"] = steps
    result.update(bench_check_cost(cfg, cfg.poses, quiet))
    result.update(bench_legs_checks(cfg, problem, quiet))
    result["engine_setup"] = {
        "poses": cfg.poses,
        "grasps": cfg.grasps,
        "trials": cfg.trials,
        "horizon": cfg.horizon,
        "reference_horizon": cfg.reference_horizon,
        "check_every": CHECK_EVERY,
        "checked_methods": [m for m in cfg.methods if _checked(m)],
    }
    plans, why = (None, "a quick run") if cfg.quick else sweep_plans()
    if plans is None:
        result.update(projection(jax_rates))
        result["projection_note"] = f"no sweep plans ({why})"
    else:
        by_poses = {cfg.poses: jax_rates}
        for poses in pose_buckets(plans):
            if poses in by_poses:
                continue
            at = _problem(cfg, poses)
            by_poses[poses] = {}
            for method in cfg.methods:
                _say(f"engine: {method} (JAX) at {poses} poses", quiet)
                by_poses[poses][method] = bench_jax_engine(method, cfg, at)["jax"]
        result["steps_per_s_by_poses"] = {str(p): r for p, r in by_poses.items()}
        result.update(projection_by_chunk(by_poses, plans, len(jax.local_devices())))
    result["machine"]["load_average_end"] = _load()
    return result


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=_PROG, description=_DESCRIPTION)
    p.add_argument(
        "--json", action="store_true", help="print one JSON object instead of a table"
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="smaller problem and fewer repeats, table methods only (about a minute)",
    )
    p.add_argument(
        "--methods",
        nargs="+",
        action="extend",
        choices=_all_methods(),
        metavar="METHOD",
        help="methods to time besides the table's three (default: none with "
        "--quick, all seven otherwise); a method not timed is projected at the rate "
        "of one with the same per-step work",
    )
    p.add_argument(
        "--quiet", action="store_true", help="no progress messages on stderr"
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    cfg = settings(args.quick, args.methods)
    _set_host_devices()
    quiet = args.quiet or args.json
    try:
        result = run(cfg, quiet=quiet)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(result, indent=1, sort_keys=True))
    else:
        print(format_table(result))
    return 0
