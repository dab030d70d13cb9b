"""Running a sweep: :func:`run` from Python, and the work behind
``python -m legs_jax.sweep``.

    from legs_jax import sweep

    out = sweep.run(experiment=["main"], objects=["bar_clamp"], methods=["legs"],
                    trials=2, rollouts=2, horizon=300)
    # out == Path("runs/main-bar_clamp-legs-T2-R2-H300"): out/main/runs.parquet ...

A configuration is a :class:`~legs_jax.sweep.config.SweepConfig`; :func:`run`
plans every selected experiment (:mod:`legs_jax.sweep.experiments`), refuses
conflicting results before running anything, runs the missing chunks
(:mod:`legs_jax.sweep.execute`) and merges them (:mod:`legs_jax.sweep.store`).
"""

from __future__ import annotations

import dataclasses
import json
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import experiments
from legs_jax import results as res
from legs_jax._jax_cache import compile_cache
from legs_jax.core import problem as problem_mod
from legs_jax.sweep import execute as _execute
from legs_jax.sweep.config import RESULTS, SweepConfig, default_out, validate
from legs_jax.sweep.execute import finish_experiment, run_experiment
from legs_jax.sweep.experiments import _experiment_plan, _ProblemsMissing
from legs_jax.sweep.hosts import (
    _barrier,
    _devices,
    _init_distributed,
    _set_device_flags,
    _wait_for_chunks,
)
from legs_jax.sweep.plan import ExperimentPlan, SweepError, _say
from legs_jax.sweep.store import (
    _chunk_ok,
    _complete_and_current,
    _damaged_tables,
    _exp_dir,
    _merged_without_chunks,
    _prepare_dir,
    _warn_damaged_tables,
)
from precompute import catalog

__all__ = ["run", "run_validated"]

EXPERIMENTS = experiments.EXPERIMENTS


def run(config: SweepConfig | None = None, /, **options: Any) -> Path:
    """Run a sweep and return the folder that holds its results (one subfolder
    per experiment: ``runs.parquet``, ``curves.parquet``, ``checks.parquet``,
    ``manifest.json``; see :mod:`legs_jax.results`).

    ``config`` (a :class:`~legs_jax.sweep.config.SweepConfig`) and keyword
    options take the command line's names and defaults: ``all``, ``experiment``
    (names), ``objects``, ``problems`` (paths), ``methods`` (names, or
    ``module.path:ATTRIBUTE``), ``grid`` (``{"delta": (0.01, 0.1)}``: every
    combination), ``trials``, ``rollouts``, ``horizon``, ``seed``, ``out``,
    ``overwrite``, ``dry_run``, ``quiet``, ... (``python -m legs_jax.sweep
    --help`` explains each). Without ``out`` the results go to ``results/`` at
    the experiments' declared configuration and to a folder of their own under
    ``runs/`` otherwise. Running the same configuration again resumes it.

    Raises :class:`~legs_jax.errors.ConfigError` for a bad configuration and
    :class:`~legs_jax.sweep.plan.SweepError` when the results folder holds
    results of another configuration (``overwrite=True`` replaces them), both
    before any computation; ``KeyboardInterrupt`` leaves every finished chunk in
    place for the next run.
    """
    config = dataclasses.replace(config or SweepConfig(), **options)
    return run_validated(validate(config))


def run_validated(c: SweepConfig) -> Path:
    """:func:`run` of a configuration :func:`validate` returned; Ctrl-C stops at
    the next chunk boundary (the previous SIGINT handler is restored after)."""
    _execute._INTERRUPTED.clear()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, _execute._on_sigint)
    try:
        return _run(c)
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _run(c: SweepConfig) -> Path:
    _set_device_flags(c.devices)
    out = Path(c.out) if c.out else default_out(c)
    if not c.out and out != Path(RESULTS):
        _say(
            f"your own configuration: results go to {out}/ ({RESULTS}/ holds the "
            "paper's experiments at their declared configuration; --out DIR "
            "chooses another folder)",
            c.quiet,
        )
    names = (
        list(EXPERIMENTS)
        if (c.all or (c.smoke and not c.experiment))
        else list(dict.fromkeys(c.experiment))
    )
    started = False
    try:
        dist = _init_distributed(c)
        devices = _devices(c.devices)
        compile_cache(c.compile_cache)
        plans = []
        for name in names:
            own_prior = getattr(experiments.get(name), "PRIOR", None)
            if c.problems and own_prior:
                _say(
                    f"{name}: runs the catalogue problems with the {own_prior} prior; "
                    "skipped with --problems",
                    c.quiet,
                )
                continue
            generated = [n for n, _ in getattr(experiments.get(name), "GENERATED", ())]
            others = c.objects and not set(c.objects) & set(generated)
            if generated and (c.problems or (others and len(names) > 1)):
                flag = "--problems" if c.problems else "--objects"
                _say(
                    f"{name}: runs its own generated problems; skipped with {flag}",
                    c.quiet,
                )
                continue
            try:
                plan = _experiment_plan(name, c, catalog, out)
            except _ProblemsMissing as e:
                print(
                    f"{name}: {len(e.names)} problem file(s) missing or out of date, "
                    "built first when the sweep runs (about 8 s each on 2 cores; "
                    "or now with python -m precompute --all): " + " ".join(e.names)
                )
                continue
            if plan is None:
                _say(f"{name}: none of the selected methods; skipped", c.quiet)
                continue
            plans.append(plan)
        if not plans and c.dry_run:
            return out
        if not plans:
            raise SweepError("no experiment left to run with the selected methods")
        if c.dry_run:
            for plan in plans:
                _print_plan(plan, out, c.overwrite)
            _warn_unlearnable(
                [p for p in plans if c.overwrite or not _complete_and_current(p, out)]
            )
            return out
        _check_user_methods(plans, c.quiet)
        # Refuse conflicting results of any experiment before running anything
        # (or, with --overwrite, delete them: the leader does, the others wait).
        for plan in plans:
            _prepare_dir(plan, out, c.overwrite, dist.leader)
        _barrier(dist, "legs_jax-sweep-setup")
        started = True
        t0 = time.perf_counter()
        statuses, sessions = {}, {}
        for plan in plans:
            _warn_damaged_tables(plan, out)
        kept = [p.name for p in plans if _merged_without_chunks(p, out)]
        for name in kept:
            _say(
                f"{name}: complete results already in {_exp_dir(out, name)} "
                "(chunk files not kept); nothing to run, --overwrite recomputes them",
                c.quiet,
            )
            statuses[name] = "already complete"
        complete = [
            p.name
            for p in plans
            if p.name not in kept and _complete_and_current(p, out)
        ]
        for name in complete:
            _say(
                f"{name}: complete in {_exp_dir(out, name)}; nothing to run, every "
                "file left as it is (--overwrite recomputes it)",
                c.quiet,
            )
            statuses[name] = "already complete"
        kept += complete
        plans = [p for p in plans if p.name not in kept]
        _warn_unlearnable(plans)
        for plan in plans:
            sessions[plan.name] = run_experiment(
                plan,
                out,
                devices=devices,
                dist=dist,
                quiet=c.quiet,
                reuse=not c.no_reuse,
            )
            if dist.num_processes == 1:
                statuses[plan.name] = finish_experiment(
                    plan, out, sessions[plan.name], c.quiet
                )
        if dist.num_processes > 1:
            # Every process has finished its chunks; the leader merges.
            _wait_for_chunks(dist, plans, out)
            _barrier(dist, "legs_jax-sweep-done")
            for plan in plans:
                statuses[plan.name] = (
                    finish_experiment(plan, out, sessions[plan.name], c.quiet)
                    if dist.leader
                    else "computed"
                )
        summary = ", ".join(f"{k} {v}" for k, v in statuses.items())
        _say(f"done in {time.perf_counter() - t0:.1f} s: {summary}", c.quiet)
        return out
    except KeyboardInterrupt:
        if not started:
            _say("interrupted before any chunk ran; nothing was written")
        raise


def _check_user_methods(plans: Sequence[ExperimentPlan], quiet: bool) -> None:
    """Run the conformance checks on every method from outside the package
    (:mod:`legs_jax.runtime.conformance`) before any chunk; a failure is a
    one-line error."""
    from legs_jax.core import methods  # jax: not at sweep start-up
    from legs_jax.runtime import conformance  # jax: not at sweep start-up

    names = {a.method for p in plans for a in p.arms}
    for name in sorted(n for n in names if not methods.builtin(n)):
        _say(f"{name}: conformance checks (jit, jit-vmap, masks, finite)", quiet)
        conformance.check(methods.get(name))


def _warn_unlearnable(plans: Sequence[ExperimentPlan]) -> None:
    """Say, before any chunk runs, which problems have poses in which no method
    can learn (:func:`legs_jax.core.problem.unlearnable_poses`): their gaps then
    measure the problem, not the methods."""
    seen: set[str] = set()
    for plan in plans:
        for o in plan.objects:
            if o.path in seen:
                continue
            seen.add(o.path)
            flags = problem_mod.unlearnable_poses(problem_mod.load(o.path))
            for line in problem_mod.describe_unlearnable(flags):
                print(f"warning: {o.name} ({o.path}): {line}", file=sys.stderr)


def _print_plan(plan: ExperimentPlan, out: Path, overwrite: bool = False) -> None:
    """What the run would do: nothing for a complete experiment (as the run
    decides it), a refusal for another configuration, else the chunks to run;
    with ``overwrite``, every chunk, after deleting what is there."""

    d = _exp_dir(out, plan.name)
    if overwrite:
        gone = " (deleting the results in it first)" if d.exists() else ""
        print(
            f"{plan.name}: {len(plan.objects)} object(s), {len(plan.arms)} arm(s), "
            f"T={plan.trials} R={plan.rollouts} H={plan.horizon}, "
            f"--overwrite: all {len(plan.chunks)} chunk(s), "
            f"{sum(c.rollouts for c in plan.chunks)} rollouts to run -> {d}{gone}"
        )
        for c in plan.chunks:
            print(f"  {c.id}: {c.rollouts} rollouts, P={c.num_poses} K={c.num_grasps}")
        return
    try:
        with open(d / "manifest.json") as fh:
            old = json.load(fh)
    except (OSError, json.JSONDecodeError):
        old = None
    if old is not None and old.get("config_hash") != res.config_hash(plan.config()):
        print(
            f"{plan.name}: {d} holds results of another configuration; the run "
            "would refuse them (--overwrite replaces them, --out writes elsewhere)"
        )
        return
    if old is not None and old.get("status") == "complete":
        why = _damaged_tables(d, old)
        if why is not None:
            print(f"{plan.name}: the merged tables in {d} are damaged ({why})")
    if old is not None and (
        _merged_without_chunks(plan, out) or _complete_and_current(plan, out)
    ):
        print(f"{plan.name}: complete in {d}; the run would compute nothing")
        return
    todo = [c for c in plan.chunks if not _chunk_ok(d / "chunks", c.id)]
    print(
        f"{plan.name}: {len(plan.objects)} object(s), {len(plan.arms)} arm(s), "
        f"T={plan.trials} R={plan.rollouts} H={plan.horizon}, "
        f"{len(plan.chunks)} chunk(s) ({len(plan.chunks) - len(todo)} done), "
        f"{sum(c.rollouts for c in todo)} rollouts to run -> {d}"
    )
    for c in todo:
        print(f"  {c.id}: {c.rollouts} rollouts, P={c.num_poses} K={c.num_grasps}")
