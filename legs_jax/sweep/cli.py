"""The command line: ``python -m legs_jax.sweep`` (see the package docstring)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

import experiments
from legs_jax._cli import compile_cache_arg, quiet_arg
from legs_jax.core.problem import ProblemFileError
from legs_jax.errors import ConfigError
from legs_jax.sweep.config import SweepConfig, validate
from legs_jax.sweep.driver import run_validated
from legs_jax.sweep.plan import SMOKE, SweepError
from precompute.errors import PrecomputeError

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


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    try:
        config = validate(SweepConfig.from_namespace(a))
    except ConfigError as e:
        parser.error(str(e))
    try:
        run_validated(config)
    except KeyboardInterrupt:
        return 130
    except (SweepError, ConfigError, ProblemFileError, PrecomputeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0
