"""The command line: ``python -m legs_jax.sweep`` (see the package docstring)."""

from __future__ import annotations

import argparse
import difflib
import itertools
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import experiments
from legs_jax import results as res
from legs_jax._cli import compile_cache_arg, quiet_arg
from legs_jax._jax_cache import compile_cache
from legs_jax.sweep.execute import finish_experiment, run_experiment
from legs_jax.sweep.experiments import (
    _catalog,
    _experiment_plan,
    _precompute_errors,
    _ProblemsMissing,
)
from legs_jax.sweep.hosts import (
    _barrier,
    _devices,
    _init_distributed,
    _set_device_flags,
    _wait_for_chunks,
)
from legs_jax.sweep.plan import SMOKE, ExperimentPlan, SweepError, _say
from legs_jax.sweep.store import (
    _chunk_ok,
    _complete_and_current,
    _damaged_tables,
    _exp_dir,
    _merged_without_chunks,
    _prepare_dir,
    _warn_damaged_tables,
)

# ====================================================================== arguments
EXPERIMENTS = experiments.EXPERIMENTS

_PROG = "python -m legs_jax.sweep"
_DESCRIPTION = (
    "Run the paper's experiments, or your own configuration of them, as "
    "resumable, chunked sweeps and write tidy parquet results under "
    "OUT/<experiment>/: runs.parquet (one "
    "row per run), curves.parquet (gap every 10 steps, mean and standard "
    "error over the T x R runs of each object, method and hyperparameters), "
    "checks.parquet (one row per Dirichlet check), manifest.json. Re-running "
    "the same command resumes: finished chunks are kept and checked against "
    "the configuration."
)
_EPILOG = (
    "Experiments: "
    + "; ".join(f"{n} ({experiments.get(n).DESCRIPTION})" for n in EXPERIMENTS)
    + ". Multi-host: start the same command on every host with --coordinator "
    "HOST:PORT --num-processes N --process-id I (I = 0..N-1) and a shared "
    "--out; each process takes every N-th chunk and process 0 merges."
)


def _int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected an integer, got {text!r}"
            ) from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {v}")
        return v

    return parse


_positive_int = _int_at_least(1)
_nonneg_int = _int_at_least(0)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=_PROG, description=_DESCRIPTION, epilog=_EPILOG)
    # Every list option is action="extend": given twice, its values add up
    # (argparse's default keeps only the last, silently running another grid).
    what = p.add_argument_group("what to run")
    what.add_argument("--all", action="store_true", help="run every experiment")
    what.add_argument(
        "--experiment",
        nargs="+",
        action="extend",
        metavar="NAME",
        help=f"experiments to run: {', '.join(EXPERIMENTS)}",
    )
    what.add_argument(
        "--objects",
        nargs="+",
        action="extend",
        metavar="NAME",
        help="run on these objects or sets (dexnet_adv, egad_eval) instead of each "
        "experiment's own list (from the shipped problem set, or built with "
        "--problem-source built)",
    )
    what.add_argument(
        "--problems",
        nargs="+",
        action="extend",
        metavar="PATH",
        help="run on these problem files (e.g. made by precompute --mesh) instead "
        "of the catalogue objects",
    )
    what.add_argument(
        "--problem-source",
        choices=["shipped", "built"],
        default="shipped",
        help="the catalogue objects' problem files: shipped (default; "
        "data/problemset, the files the committed results are made from, the same "
        "on every machine) or built (made from the meshes on this machine by "
        "precompute, built when missing; their bits depend on the processor)",
    )
    what.add_argument(
        "--methods",
        nargs="+",
        action="extend",
        metavar="NAME",
        help="run only these methods (separated by spaces or commas): registered "
        "names (python -c 'from legs_jax.core import methods; print(methods.names())') "
        "or module.path:ATTRIBUTE for a method of your own; a method that no "
        "experiment declares (your own, or an extra such as Bayes-UCB) runs in each "
        "selected experiment with its default hyperparameters",
    )
    what.add_argument(
        "--grid",
        nargs="+",
        action="extend",
        metavar="NAME=V1,V2",
        help="run the --methods that have these hyperparameters on this grid (every "
        "combination of the values, as one batch axis: one compile), e.g. --grid "
        "delta=0.01,0.05,0.1 s=0,1,2; results carry the values in their columns",
    )
    size = p.add_argument_group("sizes (default: each experiment's own)")
    size.add_argument("--trials", type=_positive_int, help="trials T (reservoirs)")
    size.add_argument("--rollouts", type=_positive_int, help="rollouts R per trial")
    size.add_argument("--horizon", type=_positive_int, help="horizon H (steps)")
    size.add_argument("--seed", type=_nonneg_int, default=0, help="seed (default 0)")
    size.add_argument(
        "--smoke",
        action="store_true",
        help=f"toy size for a quick end-to-end check: synthetic problems "
        f"({SMOKE['num_poses']} poses, {SMOKE['num_grasps']} grasps) named like the "
        f"real objects (at most {SMOKE['max_objects']} per experiment), "
        f"T={SMOKE['trials']}, R={SMOKE['rollouts']}, H={SMOKE['horizon']}; "
        "default --out runs/smoke",
    )
    out = p.add_argument_group("output and devices")
    out.add_argument(
        "--overwrite",
        action="store_true",
        help="delete existing results of the selected experiments and start over",
    )
    out.add_argument(
        "--out",
        metavar="DIR",
        help="output folder (default: results/ for the experiments at their "
        "declared configuration, else a folder of its own under runs/ named from "
        "what differs, e.g. runs/main-bar_clamp-legs+tql)",
    )
    out.add_argument(
        "--no-reuse",
        action="store_true",
        help="compute every chunk, even when another experiment in OUT already "
        "holds identical rollouts made by this commit (by default they are copied: "
        "case_study and early_stopping repeat runs of main)",
    )
    out.add_argument(
        "--devices",
        type=_positive_int,
        metavar="N",
        help="use the first N local devices (default all: every GPU, or on a "
        "CPU-only machine one CPU device per core, at most 8); results do not "
        "depend on it",
    )
    out.add_argument(
        "--dry-run",
        action="store_true",
        help="print the plan (chunks, rollouts) and exit",
    )
    compile_cache_arg(out, "resumed and repeated sweeps skip compiling")
    quiet_arg(out)
    dist = p.add_argument_group("multi-host (jax.distributed)")
    dist.add_argument("--coordinator", metavar="HOST:PORT", help="coordinator address")
    dist.add_argument("--num-processes", type=_positive_int, metavar="N")
    dist.add_argument("--process-id", type=_nonneg_int, metavar="I")
    return p


# The folder of the paper's experiments at their declared configuration, and the
# one under which any other configuration gets a folder of its own.
RESULTS = "results"
# Files that are meshes, not problems (precompute --mesh makes a problem of them).
_MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf", ".dae", ".urdf")
RUNS = "runs"
_SLUG_MAX = 80


def own_configuration(a: argparse.Namespace) -> list[str]:
    """What makes a parsed command line differ from the experiments' declared
    configuration, as short words for a folder name (empty: the declared one)."""

    def names(values) -> str:
        return "+".join(str(v).replace(":", ".").replace("/", "_") for v in values)

    parts = []
    if a.objects:
        parts.append(names(a.objects))
    if a.problems:
        parts.append(names(Path(f).stem for f in a.problems))
    if a.methods:
        parts.append(names(a.methods))
    if a.grid:
        parts.append("grid-" + names(a.grid))
    for flag, letter in (("trials", "T"), ("rollouts", "R"), ("horizon", "H")):
        if getattr(a, flag):
            parts.append(f"{letter}{getattr(a, flag)}")
    if a.seed:
        parts.append(f"seed{a.seed}")
    if getattr(a, "problem_source", "shipped") != "shipped":
        parts.append(a.problem_source)
    return parts


def default_out(a: argparse.Namespace) -> Path:
    """Where a sweep writes without --out: ``results`` at the experiments' declared
    configuration, else a folder of its own under ``runs/`` named from what
    differs (``runs/main-bar_clamp-legs+tql``), so that a user's sweep never
    meets the shipped results."""
    if a.smoke:
        return Path(RUNS) / "smoke"
    parts = own_configuration(a)
    if not parts:
        return Path(RESULTS)
    exps = "all" if a.all else "+".join(dict.fromkeys(a.experiment or ()))
    slug = "-".join([exps, *parts])
    if len(slug) > _SLUG_MAX:
        import hashlib

        digest = hashlib.sha256(slug.encode()).hexdigest()[:8]
        slug = f"{slug[: _SLUG_MAX - 9]}-{digest}"
    return Path(RUNS) / slug


def _split_commas(values: Sequence[str] | None) -> list[str] | None:
    if values is None:
        return None
    return [x for v in values for x in v.split(",") if x]


def _parse_grid(p: argparse.ArgumentParser, items: Sequence[str]) -> dict[str, Any]:
    """``NAME=V1,V2 ...`` -> the product of the values as zipped sequences."""
    axes: dict[str, list[float]] = {}
    for item in items:
        name, eq, text = item.partition("=")
        if not eq or not name or not text:
            p.error(f"--grid: expected NAME=V1,V2,..., got {item!r}")
        if name in axes:
            p.error(f"--grid: {name} given twice")
        try:
            axes[name] = [float(x) for x in text.split(",") if x]
        except ValueError:
            p.error(f"--grid: {name} takes numbers, got {text!r}")
        if not axes[name]:
            p.error(f"--grid: no value for {name}")
    points = list(itertools.product(*axes.values()))
    return {n: tuple(pt[i] for pt in points) for i, n in enumerate(axes)}


def _validate_args(p: argparse.ArgumentParser, a: argparse.Namespace) -> None:
    if a.all and a.experiment:
        p.error("use either --all or --experiment, not both")
    if a.problems and not a.all and not a.experiment and not a.smoke:
        a.experiment = ["main"]  # problem files alone: the main configuration
    if not a.all and not a.experiment and not a.smoke:
        p.error("nothing to run: pass --all, --experiment NAME or --smoke")
    for e in a.experiment or ():
        if e not in EXPERIMENTS:
            near = difflib.get_close_matches(e, EXPERIMENTS, n=1)
            hint = f"; did you mean {near[0]}?" if near else ""
            p.error(f"unknown experiment '{e}' (known: {', '.join(EXPERIMENTS)}){hint}")
    a.methods = _split_commas(a.methods)
    if a.methods is not None and not a.methods:
        p.error("--methods: no method named")
    from legs_jax.core import methods

    known = methods.names()
    for m in a.methods or ():
        if m not in known and ":" not in m:
            near = difflib.get_close_matches(m, known, n=1)
            hint = f"; did you mean {near[0]}?" if near else ""
            p.error(
                f"unknown method '{m}' (known: {', '.join(known)}; or "
                f"module.path:ATTRIBUTE for a method of your own){hint}"
            )
    a.grid = _parse_grid(p, a.grid) if a.grid else None
    if a.grid is not None and not a.methods:
        p.error("--grid needs --methods: the methods to run on the grid")
    if a.objects and a.problems:
        p.error("use either --objects or --problems, not both")
    for f in a.problems or ():
        if not Path(f).is_file():
            p.error(f"--problems: no such file: {f}")
        suffix = Path(f).suffix.lower()
        if suffix in _MESH_SUFFIXES:
            p.error(
                f"--problems takes problem files (.npz); {f} is a mesh: build its "
                f"problem first with `python -m precompute --mesh {f} --units mm` "
                "(say the mesh's units), then pass the .npz file it prints"
            )
        if suffix != ".npz":
            p.error(
                f"--problems takes problem files (.npz, as `python -m precompute "
                f"--mesh` writes them); {f} is not one"
            )
    dist = (a.coordinator, a.num_processes, a.process_id)
    if any(x is not None for x in dist) and not all(x is not None for x in dist):
        p.error("--coordinator, --num-processes and --process-id go together")
    if a.num_processes is not None and a.process_id >= a.num_processes:
        p.error(f"--process-id must be < --num-processes ({a.num_processes})")


def _check_user_methods(plans: Sequence[ExperimentPlan], quiet: bool) -> None:
    """Run the conformance checks on every method from outside the package
    (:mod:`legs_jax.core.methods.conformance`) before any chunk; a failure is a
    one-line error."""
    from legs_jax.core import methods
    from legs_jax.core.methods import conformance

    names = {a.method for p in plans for a in p.arms}
    for name in sorted(n for n in names if not methods.builtin(n)):
        _say(f"{name}: conformance checks (jit, jit-vmap, masks, finite)", quiet)
        conformance.check(methods.get(name))


def _warn_unlearnable(plans: Sequence[ExperimentPlan]) -> None:
    """Say, before any chunk runs, which problems have poses in which no method
    can learn (:func:`legs_jax.core.problem.unlearnable_poses`): their gaps then
    measure the problem, not the methods."""
    from legs_jax.core import problem as problem_mod

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
    import json

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


def main(argv: Sequence[str] | None = None) -> int:
    import signal
    import threading

    from legs_jax.sweep import execute as _execute

    _execute._INTERRUPTED.clear()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _execute._on_sigint)
    parser = build_parser()
    a = parser.parse_args(argv)
    _validate_args(parser, a)
    _set_device_flags(a.devices)
    out = Path(a.out) if a.out else default_out(a)
    if not a.out and out != Path(RESULTS):
        _say(
            f"your own configuration: results go to {out}/ ({RESULTS}/ holds the "
            "paper's experiments at their declared configuration; --out DIR "
            "chooses another folder)",
            a.quiet,
        )
    names = (
        list(EXPERIMENTS)
        if (a.all or (a.smoke and not a.experiment))
        else list(dict.fromkeys(a.experiment))
    )
    started = False
    try:
        from legs_jax.core.problem import ProblemFileError
        from legs_jax.errors import ConfigError

        dist = _init_distributed(a)
        devices = _devices(a.devices)
        compile_cache(a.compile_cache)
        catalog = _catalog()
        a.declared = experiments.declared_methods()
        plans = []
        for name in names:
            own_prior = getattr(experiments.get(name), "PRIOR", None)
            if a.problems and own_prior:
                _say(
                    f"{name}: runs the catalogue problems with the {own_prior} prior; "
                    "skipped with --problems",
                    a.quiet,
                )
                continue
            generated = [n for n, _ in getattr(experiments.get(name), "GENERATED", ())]
            others = a.objects and not set(a.objects) & set(generated)
            if generated and (a.problems or (others and len(names) > 1)):
                flag = "--problems" if a.problems else "--objects"
                _say(
                    f"{name}: runs its own generated problems; skipped with {flag}",
                    a.quiet,
                )
                continue
            try:
                plan = _experiment_plan(name, a, catalog, out)
            except _ProblemsMissing as e:
                print(
                    f"{name}: {len(e.names)} problem file(s) missing or out of date, "
                    "built first when the sweep runs (about 8 s each on 2 cores; "
                    "or now with python -m precompute --all): " + " ".join(e.names)
                )
                continue
            if plan is None:
                _say(f"{name}: none of the selected methods; skipped", a.quiet)
                continue
            plans.append(plan)
        if not plans and a.dry_run:
            return 0
        if not plans:
            raise SweepError("no experiment left to run with the selected methods")
        if a.dry_run:
            for plan in plans:
                _print_plan(plan, out, a.overwrite)
            _warn_unlearnable(
                [p for p in plans if a.overwrite or not _complete_and_current(p, out)]
            )
            return 0
        _check_user_methods(plans, a.quiet)
        # Refuse conflicting results of any experiment before running anything
        # (or, with --overwrite, delete them: the leader does, the others wait).
        for plan in plans:
            _prepare_dir(plan, out, a.overwrite, dist.leader)
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
                a.quiet,
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
                a.quiet,
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
                quiet=a.quiet,
                reuse=not a.no_reuse,
            )
            if dist.num_processes == 1:
                statuses[plan.name] = finish_experiment(
                    plan, out, sessions[plan.name], a.quiet
                )
        if dist.num_processes > 1:
            # Every process has finished its chunks; the leader merges.
            _wait_for_chunks(dist, plans, out)
            _barrier(dist, "legs_jax-sweep-done")
            for plan in plans:
                statuses[plan.name] = (
                    finish_experiment(plan, out, sessions[plan.name], a.quiet)
                    if dist.leader
                    else "computed"
                )
        summary = ", ".join(f"{k} {v}" for k, v in statuses.items())
        _say(f"done in {time.perf_counter() - t0:.1f} s: {summary}", a.quiet)
        return 0
    except KeyboardInterrupt:
        if not started:
            _say("interrupted before any chunk ran; nothing was written")
        return 130
    except (SweepError, ConfigError, ProblemFileError, *_precompute_errors()) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
