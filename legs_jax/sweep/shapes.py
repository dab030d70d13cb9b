"""The compiled programs of a sweep, and what padding to fewer shapes costs.

``python -m legs_jax.sweep.shapes`` prints, for the experiments of ``--all`` and a
few choices of pose buckets, how many distinct programs the sweep compiles (one
per method, static configuration and array shapes) and how much padded work the
planner's cost model adds over running every object at its own pose count
(BENCHMARKS.md, "Fixed costs"). It reads the problem files' headers only.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import experiments as declared
from legs_jax.sweep import experiments as planning
from legs_jax.sweep import plan as plan_mod
from legs_jax.sweep.config import SweepConfig, validate
from legs_jax.sweep.plan import ExperimentPlan
from precompute import catalog

# Bucket choices compared by the table: (pose buckets, chunks padded to their
# group's largest shapes); None: powers of two, (): none.
CANDIDATES: dict[str, tuple[tuple[int, ...] | None, bool]] = {
    "none (every pose count its own)": ((), True),
    "powers of two, each chunk its own shapes (before)": (None, False),
    "powers of two": (None, True),
    "8, 16, 32 (adopted)": ((8, 16, 32), True),
    "4, 12, 32": ((4, 12, 32), True),
    "8, 32": ((8, 32), True),
    "32": ((32,), True),
}


def _chunk_programs(plan: ExperimentPlan, c, n_dev: int):
    """(program key, rollouts, rollouts run with the mini-batch padding) of each
    static group of a chunk, as :func:`legs_jax.runtime.run` derives them."""
    from legs_jax import runtime  # jax: not at sweep start-up
    from legs_jax.core.methods.base import Config  # jax: not at sweep start-up

    arm = plan.arms[c.arm]
    m = plan_mod._method(arm.method)
    G, O, T = len(arm.grid), len(c.objects), len(c.trials)  # noqa: E741
    n_pad = runtime.table_rows(max(O * T, c.shape_of[0]))
    groups: dict[tuple[int, ...], int] = {}
    for point in arm.grid:
        d = dict(point)
        st = tuple(int(d[n]) for n in m.static)
        groups[st] = groups.get(st, 0) + 1
    for st, g in groups.items():
        cfg = Config(
            num_poses=c.num_poses,
            num_grasps=c.num_grasps,
            **dict(zip(m.static, st, strict=True)),
        )
        rows = g * O * T * plan.rollouts
        like = max(rows, c.shape_of[1] * g // G)
        per = runtime.mini_batch_rows(m, cfg, like, n_dev, "cpu")
        every = plan.check_every if c.record_checks else None
        key = (m.name, cfg, every, c.record_active_set, n_pad, per)
        run = -(-rows // (per * n_dev)) * per * n_dev
        yield key, rows, run


def program_keys(plans: Sequence[ExperimentPlan], n_dev: int) -> set[tuple[Any, ...]]:
    """The distinct programs the engine compiles for these plans on ``n_dev`` CPU
    devices: (method, static configuration, checks, active set, table rows,
    rollouts a device)."""
    return {
        key
        for plan in plans
        for c in plan.chunks
        for key, _, _ in _chunk_programs(plan, c, n_dev)
    }


def padded_work(plans: Sequence[ExperimentPlan], n_dev: int) -> float:
    """Work run (padded poses and padded mini-batches) over the work of every
    object at its own pose count, by the planner's cost model."""
    padded = own = 0.0
    for plan in plans:
        for c in plan.chunks:
            arm = plan.arms[c.arm]
            every = plan.check_every if c.record_checks else 0
            per_object = len(arm.grid) * len(c.trials) * plan.rollouts
            w = plan_mod._rollout_work(
                arm, c.num_poses, c.num_grasps, plan.horizon, every
            )
            rows = run = 0
            for _, r, rr in _chunk_programs(plan, c, n_dev):
                rows, run = rows + r, run + rr
            padded += w * per_object * len(c.objects) * run / rows
            for i in c.objects:
                p = plan.objects[i].num_poses
                own += per_object * plan_mod._rollout_work(
                    arm, p, c.num_grasps, plan.horizon, every
                )
    return padded / own if own else 1.0


def tradeoff(
    make_plans, n_dev: int = 2, candidates: dict | None = None
) -> list[dict[str, Any]]:
    """Programs and padded work of each bucket choice; ``make_plans()`` plans the
    experiments, which are chunked again under each choice."""
    rows = []
    for label, (choice, grouped) in (candidates or CANDIDATES).items():
        plans = make_plans()
        for plan in plans:
            plan.chunks = plan_mod.plan_chunks(plan, buckets=choice)
            if not grouped:
                plan.chunks = [
                    dataclasses.replace(c, shape_of=(0, 0)) for c in plan.chunks
                ]
        keys = program_keys(plans, n_dev)
        rows.append(
            {
                "buckets": label,
                "programs": len(keys),
                "methods": len({k[0] for k in keys}),
                "work": padded_work(plans, n_dev),
            }
        )
    return rows


def plan_all() -> list[ExperimentPlan]:
    """The plans of ``python -m legs_jax.sweep --all``, from the problem files'
    headers (a :class:`SweepError` names the missing ones)."""
    args = validate(SweepConfig(all=True, dry_run=True))
    out = []
    for name in declared.EXPERIMENTS:
        plan = planning._experiment_plan(name, args, catalog, Path("results"))
        if plan is not None:
            out.append(plan)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m legs_jax.sweep.shapes",
        description="Compiled programs of `python -m legs_jax.sweep --all` and the "
        "padded work of each choice of pose buckets (the cost model's estimate).",
    )
    p.add_argument("--devices", type=int, default=2, help="CPU devices (default 2)")
    a = p.parse_args(argv)
    rows = tradeoff(plan_all, a.devices)
    print("| pose buckets | programs compiled | work run (cost model) |")
    print("|---|---|---|")
    for r in rows:
        print(f"| {r['buckets']} | {r['programs']} | ×{r['work']:.3f} |")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
