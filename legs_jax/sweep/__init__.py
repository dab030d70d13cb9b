"""Run the paper's experiments as resumable, chunked sweeps with tidy results.

    python -m legs_jax.sweep --all                      # every experiment
    python -m legs_jax.sweep --experiment main --objects bar_clamp --methods legs tql
    python -m legs_jax.sweep --experiment main --problems my_object.npz
    python -m legs_jax.sweep --smoke                    # every experiment, toy size

From Python, :func:`run` takes the same options and returns the results folder::

    from legs_jax import sweep

    out = sweep.run(experiment=["main"], objects=["bar_clamp"], methods=["legs"],
                    trials=2, rollouts=2, horizon=300)

Each experiment (declared in ``experiments/<name>/sweep.py``) is split into chunks: one
arm (method, variant and its hyperparameter grid, which runs as one batch axis), a few
objects and a block of trials, sized to bound memory and the work lost to an
interruption. Every finished chunk is written atomically under
``<out>/<experiment>/chunks/``; running the same command again skips finished chunks
(after checking that they were made with the same configuration) and, once all are
there, merges them into ``runs.parquet``, ``curves.parquet`` and ``checks.parquet`` (see
:mod:`legs_jax.results`). Results never depend on chunking, interruption, device count
or host count.

Modules: :mod:`~legs_jax.sweep.plan` (arms, chunks, cost model),
:mod:`~legs_jax.sweep.experiments` (declarations and objects to plans),
:mod:`~legs_jax.sweep.store` (chunk folders, checksums, reuse, manifests, merge),
:mod:`~legs_jax.sweep.execute` (running chunks), :mod:`~legs_jax.sweep.hosts`
(devices, multi-host), :mod:`~legs_jax.sweep.config` (the configuration),
:mod:`~legs_jax.sweep.driver` (a whole sweep: :func:`run`) and
:mod:`~legs_jax.sweep.cli` (the command line).
"""

from legs_jax.sweep import cli, config, driver, execute, experiments, hosts, plan, store
from legs_jax.sweep.cli import EXPERIMENTS, build_parser, main
from legs_jax.sweep.config import SweepConfig
from legs_jax.sweep.driver import run
from legs_jax.sweep.execute import finish_experiment, run_experiment
from legs_jax.sweep.plan import (
    MEMORY_BUDGET,
    WORK_BUDGET,
    Arm,
    Chunk,
    ExperimentPlan,
    ObjectEntry,
    SweepError,
    make_arm,
    plan_chunks,
)

__all__ = [
    "EXPERIMENTS",
    "MEMORY_BUDGET",
    "WORK_BUDGET",
    "Arm",
    "Chunk",
    "SweepConfig",
    "ExperimentPlan",
    "ObjectEntry",
    "SweepError",
    "build_parser",
    "cli",
    "config",
    "driver",
    "execute",
    "experiments",
    "finish_experiment",
    "hosts",
    "main",
    "make_arm",
    "plan",
    "plan_chunks",
    "run",
    "run_experiment",
    "store",
]
