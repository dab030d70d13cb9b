"""Run the paper's experiments as resumable, chunked sweeps with tidy results.

    python -m legs_jax.sweep --all                      # every experiment of SPEC §7
    python -m legs_jax.sweep --experiment main --objects bar_clamp --methods legs tql
    python -m legs_jax.sweep --experiment main --problems my_object.npz
    python -m legs_jax.sweep --smoke --out /tmp/smoke   # every experiment, toy size

Each experiment (declared in ``sweeps/``) is split into chunks: one arm (method,
variant and its hyperparameter grid, which runs as one batch axis), a few objects and
a block of trials, sized to bound memory and the work lost to an interruption.
Every finished chunk is written atomically under ``<out>/<experiment>/chunks/``;
running the same command again skips finished chunks (after checking that they
were made with the same configuration) and, once all are there, merges them into
``runs.parquet``, ``curves.parquet`` and ``checks.parquet`` (see
:mod:`legs_jax.results`). Results never depend on chunking, interruption, device
count or host count.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import hashlib
import importlib.metadata
import itertools
import math
import os
import platform
import re
import shutil
import socket
import subprocess
import sys
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import sweeps
from legs_jax import results as res

__all__ = [
    "Chunk",
    "ExperimentPlan",
    "SweepError",
    "finish_experiment",
    "main",
    "plan_chunks",
    "run_experiment",
]

# Version of the result layout; part of every configuration hash.
RESULTS_VERSION = 1

# Sizes of --smoke: synthetic problems named like the real objects.
SMOKE = dict(
    trials=1, rollouts=2, horizon=200, num_poses=4, num_grasps=200, max_objects=2
)

# Chunk budgets. Work is counted in candidate-grasp evaluations (about one exact
# Beta draw each): 8e8 holds the 100 rollouts of 3000 steps over K = 2000 grasps of
# one object (15 s on a 2-core CPU), or several objects of a cheaper method. It
# bounds what an interruption loses. Memory: the chunk's tables and results.
WORK_BUDGET = 8e8
MEMORY_BUDGET = 1.5e9
DIRICHLET_SAMPLES = 3000
# Default number of CPU devices on a CPU-only machine (one per core up to this).
MAX_DEFAULT_HOST_DEVICES = 8


class SweepError(Exception):
    """A user error of the sweep command: printed as one line, exit status 2."""


# =========================================================================== plans
@dataclasses.dataclass(frozen=True)
class ObjectEntry:
    """One object of an experiment and its problem file."""

    name: str
    set: str
    object_id: int
    path: str
    sha256: str
    num_poses: int  # P slots of the problem file
    num_grasps: int  # K slots
    num_trials: int  # T in the file


@dataclasses.dataclass(frozen=True)
class Arm:
    """A method with its hyperparameters; ``grid`` holds G full hyperparameter
    dicts (a one-point grid for a plain configuration)."""

    method: str
    variant: str
    overrides: tuple[tuple[str, Any], ...]  # as declared (sequences = grid)
    grid: tuple[tuple[tuple[str, float], ...], ...]  # [G] full hparams

    @property
    def label(self) -> str:
        return self.method + (f".{self.variant}" if self.variant else "")

    def grid_dicts(self) -> list[dict[str, float]]:
        return [dict(g) for g in self.grid]

    def engine_hparams(self) -> dict[str, Any]:
        return {k: (tuple(v) if isinstance(v, tuple) else v) for k, v in self.overrides}


@dataclasses.dataclass(frozen=True)
class Chunk:
    """A unit of work: one arm, some objects, a block of trials, all rollouts."""

    id: str
    arm: int  # index into the experiment's arms
    objects: tuple[int, ...]  # indices into the experiment's objects
    trials: tuple[int, ...]
    num_poses: int  # P the batch is padded to
    num_grasps: int  # K the batch is padded to
    record_checks: bool
    record_active_set: bool
    rollouts: int  # G x O x T x R of the chunk
    work: float  # estimated cost (progress bar units)
    hash: str
    # What each of its rollouts depends on besides (object, trial, rollout): two
    # chunks with equal signatures compute identical rows for the pairs they share
    # (see :func:`_reuse_chunk`).
    signature: str = ""


@dataclasses.dataclass
class ExperimentPlan:
    name: str
    description: str
    objects: list[ObjectEntry]
    arms: list[Arm]
    trials: int
    rollouts: int
    horizon: int
    record_every: int
    check_every: int
    check_methods: tuple[str, ...]
    active_set_methods: tuple[str, ...]
    seed: int
    smoke: bool
    chunks: list[Chunk] = dataclasses.field(default_factory=list)
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def config(self) -> dict[str, Any]:
        """Everything the results depend on (not devices, hosts or chunking)."""
        return {
            "results_version": RESULTS_VERSION,
            "experiment": self.name,
            "smoke": self.smoke,
            "objects": [
                {
                    "name": o.name,
                    "set": o.set,
                    "object_id": o.object_id,
                    "sha256": o.sha256,
                }
                for o in self.objects
            ],
            "arms": [
                {"method": a.method, "variant": a.variant, "grid": a.grid_dicts()}
                for a in self.arms
            ],
            "trials": self.trials,
            "rollouts": self.rollouts,
            "horizon": self.horizon,
            "record_every": self.record_every,
            "check_every": self.check_every,
            "check_methods": list(self.check_methods),
            "active_set_methods": list(self.active_set_methods),
            "seed": self.seed,
        }

    @property
    def total_rollouts(self) -> int:
        return sum(c.rollouts for c in self.chunks)


# ----------------------------------------------------------------------- hparams
def _method(spec: str):
    """The method named ``spec`` (registered or ``module.path:ATTRIBUTE``)."""
    from legs_jax import methods
    from legs_jax.errors import ConfigError

    try:
        return methods.resolve(spec)
    except ConfigError as e:
        raise SweepError(str(e)) from None


def make_arm(method: str, variant: str, hparams: Mapping[str, Any]) -> Arm:
    """Resolve a declared arm: scalars and equal-length sequences (a grid, zipped),
    validated by the method's own declaration (:func:`legs_jax.methods.parse_grid`).
    Every grid point holds every hyperparameter column of the results (the
    method's values, and :func:`legs_jax.methods.column_defaults` for the
    columns it does not have)."""
    from legs_jax import methods
    from legs_jax.errors import ConfigError

    m = _method(method)
    for k, v in hparams.items():
        if k in m.static and isinstance(v, list | tuple | np.ndarray):
            raise SweepError(f"{k} is static (it sets array shapes): no grid")
    try:
        g, values = methods.parse_grid(m, hparams)
    except ConfigError as e:
        raise SweepError(f"{m.name}: {e}") from None
    columns = methods.column_defaults()
    grid = []
    for i in range(g):
        point = dict(columns)
        point.update({k: v[i].item() for k, v in values.items()})
        grid.append(tuple(sorted(point.items())))
    sizes = {k for k, v in hparams.items() if isinstance(v, list | tuple | np.ndarray)}
    overrides = tuple(
        (k, tuple(float(x) for x in v) if k in sizes else v)
        for k, v in sorted(hparams.items())
    )
    return Arm(m.name, variant, overrides, tuple(grid))


# ------------------------------------------------------------------ chunk planning
def _pose_bucket(p: int) -> int:
    """Pad the pose axis to the next power of two (fewer distinct shapes, fewer
    compilations); padding is masked and never changes results."""
    return 1 << max(0, (p - 1).bit_length())


def _rollout_work(arm: Arm, P: int, K: int, horizon: int, check_every: int) -> float:
    """Cost model: the candidate grasps a step touches (the method's declared
    ``cost``; about one exact Beta draw each) plus a fixed cost a step, and the
    Dirichlet checks."""
    from legs_jax.methods.base import Config

    m = _method(arm.method)
    point = dict(arm.grid[0])
    cfg = Config(num_poses=P, num_grasps=K, **{n: point[n] for n in m.static})
    steps = horizon * (m.cost(cfg) + 32.0)
    n_checks = horizon // check_every if check_every else 0
    return steps + n_checks * DIRICHLET_SAMPLES * (P + 1)


def _trial_memory(
    P: int, K: int, G: int, R: int, cfg: ExperimentPlan, act: int
) -> float:
    """Bytes a chunk holds per (object, trial): the engine's tables of the pair
    (p, q, masks, rankings: about 20 bytes a grasp slot) and the results of its
    G x R rollouts (``act``: slots of a recorded active set, 0 for none). The
    rollout state itself lives in the engine's mini-batches."""
    c1 = cfg.horizon // cfg.record_every + 2
    c2 = cfg.horizon // cfg.check_every + 1
    per_rollout = (c1 + 4 * c2) * 4 + 256
    per_rollout += c2 * P * act * 4
    return P * K * 20 + G * R * per_rollout


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)


def _chunk_id(arm: Arm, names: Sequence[str], trials: Sequence[int]) -> str:
    tag = _safe(names[0])
    if len(names) > 1:
        h = hashlib.sha256("\n".join(names).encode()).hexdigest()[:6]
        tag += f"+{len(names) - 1}-{h}"
    return f"{_safe(arm.label)}__{tag}__t{trials[0]}-{trials[-1]}"


def plan_chunks(
    cfg: ExperimentPlan,
    work_budget: float = WORK_BUDGET,
    memory_budget: float = MEMORY_BUDGET,
) -> list[Chunk]:
    """Split an experiment into chunks, deterministically from its configuration.

    Objects of an arm are grouped by padded shape (pose bucket, K) in catalogue
    order; a chunk holds whole objects while they fit the budgets, else one object
    and an equal-sized block of its trials.
    """
    chunks: list[Chunk] = []
    for a, arm in enumerate(cfg.arms):
        G = len(arm.grid)
        record_checks = arm.method in cfg.check_methods
        record_act = arm.method in cfg.active_set_methods
        groups: OrderedDict[tuple[int, int], list[int]] = OrderedDict()
        for i, o in enumerate(cfg.objects):
            groups.setdefault((_pose_bucket(o.num_poses), o.num_grasps), []).append(i)
        for (P, K), members in groups.items():
            every = cfg.check_every if record_checks else 0
            w = _rollout_work(arm, P, K, cfg.horizon, every)
            width = int(dict(arm.grid[0]).get("k", 100)) if record_act else 0
            m = _trial_memory(P, K, G, cfg.rollouts, cfg, width)
            per_trial = G * cfg.rollouts
            cap = int(min(work_budget / (per_trial * w), memory_budget / m))
            cap = max(1, cap)
            T = cfg.trials
            if cap >= T:
                per_chunk = cap // T
                n_chunks = math.ceil(len(members) / per_chunk)
                per_chunk = math.ceil(len(members) / n_chunks)
                blocks = [
                    (members[i : i + per_chunk], tuple(range(T)))
                    for i in range(0, len(members), per_chunk)
                ]
            else:
                n_blocks = math.ceil(T / cap)
                splits = np.array_split(np.arange(T), n_blocks)
                blocks = [
                    ([i], tuple(int(t) for t in block))
                    for i in members
                    for block in splits
                ]
            for objs, trials in blocks:
                names = [cfg.objects[i].name for i in objs]
                n_roll = G * len(objs) * len(trials) * cfg.rollouts
                spec = {
                    "experiment": cfg.config(),
                    "arm": a,
                    "objects": names,
                    "trials": list(trials),
                    "pad": [P, K],
                }
                signature = {
                    "results_version": RESULTS_VERSION,
                    "seed": cfg.seed,
                    "method": arm.method,
                    "grid": arm.grid_dicts(),
                    "rollouts": cfg.rollouts,
                    "horizon": cfg.horizon,
                    "record_every": cfg.record_every,
                    "check_every": cfg.check_every if record_checks else None,
                    "record_checks": record_checks,
                    "record_active_set": record_act,
                    "pad": [P, K],
                }
                chunks.append(
                    Chunk(
                        id=_chunk_id(arm, names, trials),
                        arm=a,
                        objects=tuple(objs),
                        trials=trials,
                        num_poses=P,
                        num_grasps=K,
                        record_checks=record_checks,
                        record_active_set=record_act,
                        rollouts=n_roll,
                        work=n_roll * w,
                        hash=res.config_hash(spec),
                        signature=res.config_hash(signature),
                    )
                )
    ids = [c.id for c in chunks]
    if len(set(ids)) != len(ids):  # pragma: no cover - names are unique per plan
        raise SweepError("internal error: duplicate chunk ids")
    return chunks


# ======================================================================== objects
def _precompute_errors() -> tuple[type[BaseException], ...]:
    """The user-error exception of ``precompute``, when it has one."""
    try:
        from precompute.errors import PrecomputeError
    except ImportError:
        return ()
    return (PrecomputeError,)


def _catalog():
    """The object catalogue of ``precompute``, or None when it is not available."""
    try:
        from precompute import catalog
    except ImportError:
        return None
    if not hasattr(catalog, "objects"):
        return None
    return catalog


def _name_object_id(name: str) -> int:
    """Stable object id of a problem outside the catalogue (SPEC §2 contract)."""
    from legs_jax.keys import object_id_from_name

    return int(object_id_from_name(name))


def _peek_shapes(path: str | os.PathLike) -> dict[str, tuple[int, ...]]:
    """Array shapes of a problem file without loading the arrays."""
    import zipfile

    shapes = {}
    with zipfile.ZipFile(path) as z:
        for member in ("landing.npy", "robustness.npy"):
            with z.open(member) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _, _ = np.lib.format.read_array_header_1_0(fh)
                elif version == (2, 0):
                    shape, _, _ = np.lib.format.read_array_header_2_0(fh)
                else:
                    with z.open(member) as full:
                        shape = np.lib.format.read_array(full).shape
                shapes[member[:-4]] = tuple(shape)
    return shapes


def _resolve_names(requested: Sequence[str], catalog) -> list[tuple[str, str, int]]:
    """(name, set, object_id) of set or object names, in catalogue order."""
    infos = list(catalog.objects())
    by_name = {i.name: i for i in infos}
    sets: OrderedDict[str, list] = OrderedDict()
    for i in infos:
        sets.setdefault(i.set, []).append(i)
    chosen: list = []
    for r in requested:
        if r in sets:
            chosen.extend(sets[r])
        elif r in by_name:
            chosen.append(by_name[r])
        else:
            known = list(sets) + list(by_name)
            near = difflib.get_close_matches(r, known, n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise SweepError(
                f"unknown object or set '{r}' (sets: {', '.join(sets)}; "
                f"objects: {', '.join(by_name)}){hint}"
            )
    seen = set()
    out = []
    for i in chosen:
        if i.name not in seen:
            seen.add(i.name)
            out.append((i.name, i.set, int(i.object_id)))
    rank = {i.name: n for n, i in enumerate(infos)}
    out.sort(key=lambda x: rank[x[0]])
    return out


def _entry(
    name: str, set_: str, object_id: int, path: str | os.PathLike
) -> ObjectEntry:
    from legs_jax import problem as problem_mod

    try:
        shapes = _peek_shapes(path)
    except Exception:  # noqa: BLE001 - refuse any unreadable file the same way
        problem_mod.load(path)  # raises ProblemFileError naming the field
        raise
    T, P, K = shapes["robustness"]
    return ObjectEntry(
        name=name,
        set=set_,
        object_id=object_id,
        path=str(path),
        sha256=res.sha256_file(path),
        num_poses=int(P),
        num_grasps=int(K),
        num_trials=int(T),
    )


def _user_problems(paths: Sequence[str], catalog) -> list[ObjectEntry]:
    from legs_jax import problem as problem_mod

    known = {}
    if catalog is not None:
        known = {i.name: i for i in catalog.objects()}
    entries = []
    for p in paths:
        pb = problem_mod.load(p)  # validates; ProblemFileError names file and field
        meta = pb.meta or {}
        if "object_id" in meta:
            oid = int(meta["object_id"])
        elif (
            pb.name in known
            and meta.get("set", known[pb.name].set) == known[pb.name].set
        ):
            oid = int(known[pb.name].object_id)
        else:
            oid = _name_object_id(pb.name)
        set_ = str(
            meta.get("set", known[pb.name].set if pb.name in known else "custom")
        )
        entries.append(_entry(pb.name, set_, oid, p))
    names = [e.name for e in entries]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SweepError(f"--problems: several files hold the object {dup[0]!r}")
    return entries


def _smoke_problems(names: Sequence[str], catalog, folder: Path) -> list[ObjectEntry]:
    """Synthetic problems at smoke size, named like the real objects."""
    from legs_jax import problem as problem_mod
    from legs_jax import synthetic

    known = {}
    if catalog is not None:
        known = {i.name: i for i in catalog.objects()}
    entries = []
    for name in names:
        info = known.get(name)
        oid = int(info.object_id) if info is not None else _name_object_id(name)
        set_ = info.set if info is not None else "synthetic"
        path = folder / f"{_safe(name)}.npz"
        if not path.is_file():
            pb = synthetic.make_problem(
                seed=oid,
                num_poses=SMOKE["num_poses"],
                num_grasps=SMOKE["num_grasps"],
                num_trials=SMOKE["trials"],
                name=name,
            )
            pb = dataclasses.replace(
                pb, meta={**pb.meta, "synthetic": True, "smoke": True}
            )
            problem_mod.save(pb, path)
        entries.append(_entry(name, set_, oid, path))
    return entries


# ====================================================================== arguments
EXPERIMENTS = sweeps.EXPERIMENTS


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {v}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m legs_jax.sweep",
        description=(
            "Run the paper's experiments (SPEC §7) as resumable, chunked sweeps and "
            "write tidy parquet results under OUT/<experiment>/: runs.parquet (one "
            "row per run), curves.parquet (gap every 10 steps, mean and standard "
            "error over the T x R runs of each object, method and hyperparameters), "
            "checks.parquet (one row per Dirichlet check), manifest.json. Re-running "
            "the same command resumes: finished chunks are kept and checked against "
            "the configuration."
        ),
        epilog=(
            "Experiments: main (Table I), case_study (Fig. 3), early_stopping "
            "(Sec. 5.4, Fig. 4), prior_strength and confidence (appendix). "
            "Multi-host: start the same command on every host with --coordinator "
            "HOST:PORT --num-processes N --process-id I (I = 0..N-1) and a shared "
            "--out; each process takes every N-th chunk and process 0 merges."
        ),
    )
    what = p.add_argument_group("what to run")
    what.add_argument("--all", action="store_true", help="run every experiment")
    what.add_argument(
        "--experiment",
        nargs="+",
        metavar="NAME",
        help=f"experiments to run: {', '.join(EXPERIMENTS)}",
    )
    what.add_argument(
        "--objects",
        nargs="+",
        metavar="NAME",
        help="run on these objects or sets (dexnet_adv, egad_eval) instead of each "
        "experiment's own list; problem files are built when missing",
    )
    what.add_argument(
        "--problems",
        nargs="+",
        metavar="PATH",
        help="run on these problem files (e.g. made by precompute --mesh) instead "
        "of the catalogue objects",
    )
    what.add_argument(
        "--methods",
        nargs="+",
        metavar="NAME",
        help="run only these methods (separated by spaces or commas): registered "
        "names (python -c 'from legs_jax import methods; print(methods.names())') "
        "or module.path:ATTRIBUTE for a method of your own; a method that no "
        "experiment declares (your own, or an extra such as Bayes-UCB) runs in each "
        "selected experiment with its default hyperparameters",
    )
    what.add_argument(
        "--grid",
        nargs="+",
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
        "default --out results/_scratch/smoke",
    )
    out = p.add_argument_group("output and devices")
    out.add_argument("--out", metavar="DIR", help="output folder (default results)")
    out.add_argument(
        "--overwrite",
        action="store_true",
        help="delete existing results of the selected experiments and start over",
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
    out.add_argument(
        "--compile-cache",
        metavar="DIR",
        help="JAX persistent compilation cache, so that resumed and repeated sweeps "
        "skip compiling (default $JAX_COMPILATION_CACHE_DIR, else "
        "$XDG_CACHE_HOME/legs_jax/jax or ~/.cache/legs_jax/jax; 'off' disables)",
    )
    out.add_argument("--quiet", action="store_true", help="no progress bar")
    dist = p.add_argument_group("multi-host (jax.distributed)")
    dist.add_argument("--coordinator", metavar="HOST:PORT", help="coordinator address")
    dist.add_argument("--num-processes", type=_positive_int, metavar="N")
    dist.add_argument("--process-id", type=_nonneg_int, metavar="I")
    return p


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
    from legs_jax import methods

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
    dist = (a.coordinator, a.num_processes, a.process_id)
    if any(x is not None for x in dist) and not all(x is not None for x in dist):
        p.error("--coordinator, --num-processes and --process-id go together")
    if a.num_processes is not None and a.process_id >= a.num_processes:
        p.error(f"--process-id must be < --num-processes ({a.num_processes})")


def _compile_cache(option: str | None) -> str | None:
    """Turn on JAX's persistent compilation cache (results do not depend on it)."""
    if option == "off":
        return None
    path = option or os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if not path:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(
            os.path.expanduser("~"), ".cache"
        )
        path = os.path.join(base, "legs_jax", "jax")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None  # a read-only home: run without the cache
    import jax

    jax.config.update("jax_compilation_cache_dir", path)
    return path


def _set_device_flags(n: int | None) -> None:
    """Ask XLA for host (CPU) devices: ``n``, or by default one per core (at most
    8), since separate CPU devices run rollouts in parallel. It only matters on a
    CPU-only machine, takes effect only before JAX starts, and an explicit
    ``--xla_force_host_platform_device_count`` in XLA_FLAGS wins."""
    if n is None:
        n = min(os.cpu_count() or 1, MAX_DEFAULT_HOST_DEVICES)
    flags = os.environ.get("XLA_FLAGS", "")
    if n < 2 or "xla_force_host_platform_device_count" in flags:
        return
    os.environ["XLA_FLAGS"] = (
        flags + f" --xla_force_host_platform_device_count={n}"
    ).strip()


# ===================================================================== experiments
def _experiment_plan(
    name: str, a: argparse.Namespace, catalog, out: Path
) -> ExperimentPlan | None:
    import sweeps

    mod = sweeps.get(name)
    arms = _arms(mod.ARMS, a.methods, a.grid, getattr(a, "declared", set()))
    if not arms:
        return None
    trials = a.trials or (SMOKE["trials"] if a.smoke else mod.TRIALS)
    rollouts = a.rollouts or (SMOKE["rollouts"] if a.smoke else mod.ROLLOUTS)
    horizon = a.horizon or (SMOKE["horizon"] if a.smoke else mod.HORIZON)
    if a.problems:
        objects = _user_problems(a.problems, catalog)
    else:
        requested = list(a.objects) if a.objects else None
        if a.smoke:
            names = requested or list(mod.SMOKE_OBJECTS)[: SMOKE["max_objects"]]
            if catalog is not None:
                names = [n for n, _, _ in _resolve_names(names, catalog)]
            objects = _smoke_problems(names, catalog, out / "_smoke_problems")
        else:
            if catalog is None:
                raise SweepError(
                    "the object catalogue (precompute.catalog) is not available; "
                    "pass problem files with --problems"
                )
            resolved = _resolve_names(requested or list(mod.OBJECTS), catalog)
            objects = _catalog_problems(resolved, dry_run=bool(a.dry_run))
    plan = ExperimentPlan(
        name=name,
        description=mod.DESCRIPTION,
        objects=objects,
        arms=arms,
        trials=trials,
        rollouts=rollouts,
        horizon=horizon,
        record_every=mod.RECORD_EVERY,
        check_every=mod.CHECK_EVERY,
        check_methods=tuple(mod.CHECK_METHODS),
        active_set_methods=tuple(mod.ACTIVE_SET_METHODS),
        seed=a.seed,
        smoke=bool(a.smoke),
        extra={"rho_min": list(getattr(mod, "RHO_MIN", ()))},
    )
    _check_plan(plan)
    plan.chunks = plan_chunks(plan)
    return plan


def _arms(
    own_arms: Sequence[tuple[str, str, Mapping[str, Any]]],
    requested: Sequence[str] | None,
    grid: Mapping[str, Any] | None,
    declared: set[str] | frozenset[str] = frozenset(),
) -> list[Arm]:
    """The arms to run: the experiment's own, or those of the ``requested``
    methods (a method that no experiment declares, not in ``declared``, such as
    the user's own, runs with its defaults); with a ``grid``, each requested
    method that has all of its hyperparameters runs on it instead."""
    if not requested:
        return [make_arm(m, v, hp) for m, v, hp in own_arms]
    arms: list[Arm] = []
    if grid is not None:
        names = [_method(spec).defaults() for spec in requested]
        for g in grid:
            if not any(g in known for known in names):
                raise SweepError(
                    f"--grid: {g} is not a hyperparameter of "
                    f"{' or '.join(_method(x).name for x in requested)}"
                )
    for spec in requested:
        m = _method(spec)
        name = m.name
        if grid is not None and set(grid) <= set(m.defaults()):
            arms.append(make_arm(spec, "", grid))
            continue
        own = [make_arm(m, v, hp) for m, v, hp in own_arms if m == name]
        if not own and name not in declared:
            own = [make_arm(spec, "", {})]
        arms.extend(own)
    labels = [a.label for a in arms]
    if len(set(labels)) != len(labels):
        raise SweepError(f"--methods names a method twice: {', '.join(labels)}")
    order = {m: i for i, (m, _, _) in enumerate(own_arms)}
    arms.sort(key=lambda a: order.get(a.method, len(order)))
    return arms


class _ProblemsMissing(Exception):
    """Dry run: these catalogue problem files would be built first."""

    def __init__(self, names: Sequence[str]):
        super().__init__(" ".join(names))
        self.names = list(names)


def _missing_problems(names: Sequence[str]) -> list[str]:
    """Catalogue objects whose problem file is missing or out of date."""
    import precompute

    return [i.name for i in precompute.out_of_date(list(names))]


def _catalog_problems(
    resolved: Sequence[tuple[str, str, int]], *, dry_run: bool = False
) -> list[ObjectEntry]:
    try:
        import precompute
    except ImportError:  # pragma: no cover - the package ships with legs_jax
        precompute = None
    if precompute is None or not hasattr(precompute, "ensure"):
        raise SweepError(
            "problem building (precompute.ensure) is not available; "
            "pass problem files with --problems"
        )
    if dry_run:
        missing = _missing_problems([n for n, _, _ in resolved])
        if missing:
            raise _ProblemsMissing(missing)
    paths = precompute.ensure([n for n, _, _ in resolved])
    return [_entry(n, s, oid, paths[n]) for n, s, oid in resolved]


def _check_plan(plan: ExperimentPlan) -> None:
    from legs_jax.errors import ConfigError

    for o in plan.objects:
        if plan.trials > o.num_trials:
            raise SweepError(
                f"{plan.name}: object '{o.name}' has {o.num_trials} trials, "
                f"--trials {plan.trials} asked for more"
            )
        for arm in plan.arms:
            m = _method(arm.method)
            if m.check is None:
                continue
            hp = {n: np.array([dict(g)[n] for g in arm.grid]) for n in m.defaults()}
            try:
                m.check(hp, o.num_grasps)
            except ConfigError as e:
                raise SweepError(f"{plan.name}: {e} ('{o.name}')") from None
    if plan.check_every > plan.horizon and plan.check_methods:
        # No check would happen: record none rather than refuse.
        plan.check_methods = ()


# ======================================================================== devices
def _devices(n: int | None):
    import jax

    local = jax.local_devices()
    if n is not None and n > len(local):
        raise SweepError(
            f"--devices {n}: only {len(local)} local device(s) "
            f"({local[0].platform}) are available"
        )
    return local[: n or len(local)]


def _device_info(devices) -> dict[str, Any]:
    return {
        "platform": devices[0].platform,
        "kind": devices[0].device_kind,
        "count": len(devices),
    }


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("legs_jax", "jax", "jaxlib", "numpy", "scipy", "pandas", "pyarrow"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _portable_path(path: str | os.PathLike) -> str:
    """``path`` relative to the working directory or to the repository when it lies
    under one of them (so results name no machine-specific folder), else as
    given."""
    p = Path(path).resolve()
    for base in (Path.cwd().resolve(), Path(__file__).resolve().parents[1]):
        try:
            return p.relative_to(base).as_posix()
        except ValueError:
            continue
    return str(path)


def _git_commit() -> dict[str, Any]:
    """The commit of the code and whether tracked files other than ``results/``
    (which a sweep rewrites) differ from it."""
    root = Path(__file__).resolve().parent.parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        )
        if commit.returncode != 0:
            return {"commit": None}
        dirty = subprocess.run(
            [
                "git",
                "status",
                "--porcelain",
                "--untracked-files=no",
                "--",
                ".",
                ":(exclude)results",
            ],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=10,
        )
        return {"commit": commit.stdout.strip(), "dirty": bool(dirty.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None}


# ====================================================================== execution
def _engine():
    """The rollout engine module (imported late: JAX must start after the device
    flags are set)."""
    from legs_jax import engine

    return engine


class _ProblemCache:
    """Loaded problems, least recently used first out."""

    def __init__(self, capacity: int = 16):
        self.capacity = capacity
        self._items: OrderedDict[str, Any] = OrderedDict()

    def get(self, path: str):
        from legs_jax import problem as problem_mod

        if path in self._items:
            self._items.move_to_end(path)
            return self._items[path]
        pb = problem_mod.load(path)
        self._items[path] = pb
        while len(self._items) > self.capacity:
            self._items.popitem(last=False)
        return pb


def _run_chunk(
    plan: ExperimentPlan,
    chunk: Chunk,
    cache: _ProblemCache,
    devices,
    progress: Callable[[float], None] | None,
):
    """Compute one chunk; returns its tables."""
    from legs_jax import problem as problem_mod

    arm = plan.arms[chunk.arm]
    objs = [plan.objects[i] for i in chunk.objects]
    problems = [cache.get(o.path) for o in objs]
    # The engine takes trial indices into the batch's T axis, and they are also
    # the trial numbers of the rollout keys: stack trials 0..max and select.
    batch = problem_mod.stack(
        problems,
        num_poses=chunk.num_poses,
        num_grasps=chunk.num_grasps,
        num_trials=max(chunk.trials) + 1,
    )
    result = _engine().run(
        batch,
        arm.method,
        object_ids=[o.object_id for o in objs],
        trials=list(chunk.trials),
        num_rollouts=plan.rollouts,
        horizon=plan.horizon,
        hparams=arm.engine_hparams(),
        seed=plan.seed,
        record_every=plan.record_every,
        check_every=plan.check_every if chunk.record_checks else None,
        stop_variant_attempted=True,
        record_active_set=chunk.record_active_set,
        devices=devices,
        progress=progress,
    )
    ctx = res.ChunkContext(
        experiment=plan.name,
        method=arm.method,
        variant=arm.variant,
        grid=arm.grid_dicts(),
        objects=[(o.name, o.set) for o in objs],
        trials=chunk.trials,
        rollouts=range(plan.rollouts),
        seed=plan.seed,
        horizon=plan.horizon,
        record_checks=chunk.record_checks,
        record_active_set=chunk.record_active_set,
        robustness=batch.robustness[:, list(chunk.trials)],
    )
    return res.chunk_tables(result, ctx), np.asarray(result.curve_steps).tolist()


def _object_stamp(o: ObjectEntry) -> tuple[str, int, str]:
    return (o.name, int(o.object_id), o.sha256)


class _Donors:
    """Finished chunks of the other experiments in the output folder whose rollouts
    can stand in for this experiment's: same chunk signature (method, hyperparameter
    grid, seed, sizes, what is recorded), same problem file, same trial, made by
    the same clean commit as the running code. case_study and early_stopping repeat
    runs of main this way; the copied rows are the rows a computation would give,
    because a rollout's keys depend only on (seed, object, trial, rollout)."""

    def __init__(self, out: Path, exclude: str, git: Mapping[str, Any]):
        import json

        self.index: dict[tuple[str, tuple[str, int, str], int], Path] = {}
        if not git.get("commit") or git.get("dirty", True):
            return
        for path in sorted(out.glob(f"*/chunks/*/{res.CHUNK_META}")):
            if path.parent.parent.parent.name == exclude:
                continue
            try:
                with open(path) as fh:
                    meta = json.load(fh)
            except (OSError, json.JSONDecodeError):
                continue
            if meta.get("git") != dict(git) or not meta.get("signature"):
                continue
            for stamp in meta.get("object_stamps") or ():
                for t in meta.get("trials") or ():
                    key = (meta["signature"], tuple(stamp), int(t))
                    self.index.setdefault(key, path.parent)

    def __bool__(self) -> bool:
        return bool(self.index)

    def find(self, signature: str, stamp: tuple[str, int, str], trial: int):
        return self.index.get((signature, stamp, trial))


def _reuse_chunk(plan: ExperimentPlan, chunk: Chunk, donors: _Donors):
    """The tables of ``chunk`` copied from donor chunks that hold every one of its
    (object, trial) pairs, or None when some pair has no donor. Chunks that record
    active sets are always computed (no experiment records them twice)."""
    import json

    import pandas as pd

    if chunk.record_active_set or not chunk.signature or not donors:
        return None
    sources: dict[Path, None] = {}
    for i in chunk.objects:
        for t in chunk.trials:
            d = donors.find(chunk.signature, _object_stamp(plan.objects[i]), t)
            if d is None:
                return None
            sources[d] = None
    names = [plan.objects[i].name for i in chunk.objects]
    arm = plan.arms[chunk.arm]
    parts: dict[str, list[pd.DataFrame]] = {}
    curve_steps = None
    if any(res.verify_chunk(d.parent, d.name) is not None for d in sources):
        return None  # a damaged donor: compute instead
    try:
        for d in sources:
            with open(d / res.CHUNK_META) as fh:
                steps = json.load(fh)["curve_steps"]
            if curve_steps is not None and steps != curve_steps:
                return None
            curve_steps = steps
            for t in ("runs", "checks"):
                f = d / f"{t}.parquet"
                if not f.is_file():
                    continue
                df = pd.read_parquet(f)
                df = df[df["object"].isin(names) & df["trial"].isin(chunk.trials)]
                df = df.copy()
                df["experiment"] = plan.name
                df["variant"] = arm.variant
                parts.setdefault(t, []).append(df)
    except (OSError, KeyError, ValueError):
        return None  # a donor vanished or is unreadable: compute instead
    tables = {t: pd.concat(v, ignore_index=True) for t, v in parts.items()}
    if "runs" not in tables or len(tables["runs"]) != chunk.rollouts:
        return None
    if chunk.record_checks and "checks" not in tables:
        return None
    origin = [f"{d.parent.parent.name}/{d.name}" for d in sources]
    return tables, curve_steps, origin


class _Progress:
    """tqdm bar over estimated work, showing rollouts per second and the ETA."""

    def __init__(self, total_work: float, total_rollouts: int, quiet: bool, desc: str):
        from tqdm.auto import tqdm

        self.total_rollouts = total_rollouts
        self.rollouts = 0
        self.start = time.perf_counter()
        self._chunk_base = 0.0
        self._chunk_work = 0.0
        self._shown = 0.0
        self.bar = tqdm(
            total=max(total_work, 1.0),
            disable=quiet,
            desc=desc,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}"
            "{postfix}",
            dynamic_ncols=True,
            mininterval=0.5,
        )
        self._postfix()

    def _postfix(self) -> None:
        dt = time.perf_counter() - self.start
        rate = self.rollouts / dt if dt > 0 else 0.0
        self.bar.set_postfix_str(
            f"{self.rollouts}/{self.total_rollouts} rollouts, {rate:.1f} rollouts/s",
            refresh=False,
        )

    def begin_chunk(self, work: float) -> None:
        self._chunk_base = self._shown
        self._chunk_work = work

    def fraction(self, f: float) -> None:
        """Within-chunk progress in [0, 1] (from the engine)."""
        target = self._chunk_base + self._chunk_work * min(max(float(f), 0.0), 1.0)
        if target > self._shown:
            self.bar.update(target - self._shown)
            self._shown = target

    def end_chunk(self, rollouts: int) -> None:
        self.fraction(1.0)
        self.rollouts += rollouts
        self._postfix()
        self.bar.refresh()

    def skip(self, work: float) -> None:
        self.bar.total = max(self.bar.total - work, 1.0)

    def close(self) -> None:
        self.bar.close()


def _engine_progress(bar: _Progress, rollouts: int) -> Callable[[int], None]:
    """The engine reports the number of rollouts done after each mini-batch."""

    def cb(done: int) -> None:
        bar.fraction(done / max(rollouts, 1))

    return cb


# ------------------------------------------------------------------ output folders
def _exp_dir(out: Path, name: str) -> Path:
    return out / name


def _prepare_dir(plan: ExperimentPlan, out: Path, overwrite: bool, leader: bool):
    """Check existing results against the configuration; delete them when asked."""
    d = _exp_dir(out, plan.name)
    manifest = d / "manifest.json"
    chash = res.config_hash(plan.config())
    if overwrite:
        if not leader or not d.exists():
            return d, chash
        for f in ("manifest.json", *(f"{t}.parquet" for t in _FINAL_TABLES)):
            if (d / f).exists():
                (d / f).unlink()
        if (d / "chunks").exists():
            shutil.rmtree(d / "chunks")
        return d, chash
    if manifest.is_file():
        import json

        with open(manifest) as fh:
            old = json.load(fh)
        if old.get("config_hash") != chash:
            diff = _config_diff(old.get("config", {}), plan.config())
            raise SweepError(
                f"{d} holds results of a different configuration (differs in: "
                f"{diff}); pass --overwrite to replace them or --out for another folder"
            )
    # Finished chunks of this plan must match it.
    chunks_dir = d / "chunks"
    for c in plan.chunks:
        if _chunk_ok(chunks_dir, c.id):  # a damaged chunk is recomputed later
            meta = res.read_chunk_meta(chunks_dir, c.id)
            if meta.get("hash") != c.hash:
                raise SweepError(
                    f"{chunks_dir / c.id} was made with a different configuration; "
                    "pass --overwrite to replace the results"
                )
    return d, chash


def _merged_without_chunks(plan: ExperimentPlan, out: Path) -> bool:
    """The experiment's merged tables are complete and current (same problem
    files; :func:`_prepare_dir` has already refused another configuration) but
    some chunk folders are gone, as in a fresh clone of committed results:
    nothing needs recomputing."""
    import json

    d = _exp_dir(out, plan.name)
    chunks_dir = d / "chunks"
    if all(res.chunk_done(chunks_dir, c.id) for c in plan.chunks):
        return False  # the ordinary path re-merges from the chunks
    try:
        with open(d / "manifest.json") as fh:
            old = json.load(fh)
    except (OSError, json.JSONDecodeError):
        return False
    files = old.get("problem_files") or {}
    return (
        old.get("status") == "complete"
        and (d / "runs.parquet").is_file()
        and all(
            (files.get(o.name) or {}).get("sha256") == o.sha256 for o in plan.objects
        )
    )


def _chunk_ok(chunks_dir: Path, chunk_id: str) -> bool:
    """The chunk is finished and whole (:func:`legs_jax.results.verify_chunk`)."""
    return res.chunk_done(chunks_dir, chunk_id) and (
        res.verify_chunk(chunks_dir, chunk_id) is None
    )


def _drop_damaged(plan: ExperimentPlan, chunks: Sequence[Chunk], d: Path) -> int:
    """Delete the finished chunks among ``chunks`` whose files do not match their
    recorded SHA-256 (a partial copy, a disk error), with a warning that names
    each, so that they are computed again; returns how many."""
    n = 0
    for c in chunks:
        if not res.chunk_done(d / "chunks", c.id):
            continue
        why = res.verify_chunk(d / "chunks", c.id)
        if why is None:
            continue
        _say(f"warning: {plan.name}: chunk {c.id} is damaged ({why}); recomputing it")
        shutil.rmtree(d / "chunks" / c.id, ignore_errors=True)
        n += 1
    return n


def _complete_and_current(plan: ExperimentPlan, out: Path) -> bool:
    """The experiment is complete: manifest of this configuration with status
    complete, its merged tables present and every chunk whole. A run then leaves
    every file as it is."""
    import json

    d = _exp_dir(out, plan.name)
    try:
        with open(d / "manifest.json") as fh:
            old = json.load(fh)
    except (OSError, json.JSONDecodeError):
        return False
    return (
        old.get("status") == "complete"
        and old.get("config_hash") == res.config_hash(plan.config())
        and (d / "runs.parquet").is_file()
        and all(_chunk_ok(d / "chunks", c.id) for c in plan.chunks)
    )


def _config_diff(old: Mapping[str, Any], new: Mapping[str, Any]) -> str:
    keys = sorted(set(old) | set(new))
    diff = [k for k in keys if res._canonical(old.get(k)) != res._canonical(new.get(k))]
    return ", ".join(diff) or "unknown"


_FINAL_TABLES = (
    "runs",
    "curves",
    "checks",
    "active_set",
    "grasps",
    "objects",
)


def _write_manifest(
    plan: ExperimentPlan,
    d: Path,
    status: str,
    session: dict[str, Any],
) -> None:
    import json

    chunks_dir = d / "chunks"
    chunks = {}
    for c in plan.chunks:
        if _chunk_ok(chunks_dir, c.id):
            m = res.read_chunk_meta(chunks_dir, c.id)
            chunks[c.id] = {
                k: m.get(k)
                for k in (
                    "wall_s",
                    "reused_from",
                    "rollouts",
                    "device",
                    "host",
                    "process_id",
                    "git",
                    "finished",
                )
            }
    old_sessions = []
    mf = d / "manifest.json"
    if mf.is_file():
        with open(mf) as fh:
            try:
                old_sessions = json.load(fh).get("sessions", [])
            except json.JSONDecodeError:
                old_sessions = []
    sessions = [s for s in old_sessions if s.get("id") != session["id"]] + [session]
    manifest = {
        "experiment": plan.name,
        "description": plan.description,
        "status": status,
        "config": plan.config(),
        "config_hash": res.config_hash(plan.config()),
        "problem_files": {
            o.name: {"path": _portable_path(o.path), "sha256": o.sha256}
            for o in plan.objects
        },
        "seeds": {
            "seed": plan.seed,
            "rollout_key": "fold_in(fold_in(fold_in(key(seed), object_id), trial), "
            "rollout)",
            "object_ids": {o.name: o.object_id for o in plan.objects},
        },
        "git": _git_commit(),
        "git_commits_of_chunks": sorted(
            {str((c.get("git") or {}).get("commit")) for c in chunks.values()}
        ),
        "versions": _versions(),
        "chunks_total": len(plan.chunks),
        "chunks_done": len(chunks),
        "chunks": chunks,
        "wall_s_chunks": float(sum(c["wall_s"] or 0.0 for c in chunks.values())),
        "sessions": sessions,
        "curves": "aggregated: mean and standard error over the T x R runs of each "
        "object, method, variant and hyperparameters; per-run curves are in the "
        "gap_curve column of chunks/*/runs.parquet",
        "extra": plan.extra,
    }
    res.atomic_write_json(manifest, mf)


def _merge(plan: ExperimentPlan, d: Path) -> dict[str, int]:
    """Write the final tables of a complete experiment; returns their row counts."""
    import pandas as pd

    chunks_dir = d / "chunks"
    tables = res.merge_chunks(
        chunks_dir,
        [c.id for c in plan.chunks],
        [(a.method, a.variant) for a in plan.arms],
        [o.name for o in plan.objects],
    )
    for name, df in tables.items():
        res.atomic_write_parquet(df, d / f"{name}.parquet")
    objects = pd.DataFrame(
        {
            "object": [o.name for o in plan.objects],
            "set": [o.set for o in plan.objects],
            "object_id": np.array([o.object_id for o in plan.objects], np.int64),
            "num_poses": np.array([o.num_poses for o in plan.objects], np.int64),
            "num_grasps": np.array([o.num_grasps for o in plan.objects], np.int64),
            "problem_file": [_portable_path(o.path) for o in plan.objects],
            "sha256": [o.sha256 for o in plan.objects],
        }
    )
    res.atomic_write_parquet(objects, d / "objects.parquet")
    if plan.active_set_methods:
        res.atomic_write_parquet(_grasps_table(plan), d / "grasps.parquet")
    return {k: len(v) for k, v in tables.items()}


def _grasps_table(plan: ExperimentPlan):
    """Ground truth and prior of trial 0's reservoir of each object (histograms)."""
    import pandas as pd

    from legs_jax import problem as problem_mod

    frames = []
    for o in plan.objects:
        pb = problem_mod.load(o.path)
        p, g = np.nonzero(pb.valid[0])
        frames.append(
            pd.DataFrame(
                {
                    "object": o.name,
                    "trial": np.zeros(len(p), np.int64),
                    "pose": p.astype(np.int64),
                    "grasp": g.astype(np.int64),
                    "landing": pb.landing[p].astype(np.float64),
                    "robustness": pb.robustness[0][p, g].astype(np.float64),
                    "prior": pb.prior[0][p, g].astype(np.float64),
                }
            )
        )
    return pd.concat(frames, ignore_index=True)


# ============================================================================ main
@dataclasses.dataclass
class _Dist:
    num_processes: int = 1
    process_id: int = 0

    @property
    def leader(self) -> bool:
        return self.process_id == 0


def _init_distributed(a: argparse.Namespace) -> _Dist:
    if a.coordinator is None:
        return _Dist()
    import jax

    jax.distributed.initialize(
        coordinator_address=a.coordinator,
        num_processes=a.num_processes,
        process_id=a.process_id,
    )
    return _Dist(a.num_processes, a.process_id)


def _barrier(dist: _Dist, name: str) -> None:
    if dist.num_processes == 1:
        return
    from jax._src import distributed

    client = distributed.global_state.client
    if client is not None:
        client.wait_at_barrier(name, timeout_in_ms=7 * 24 * 3600 * 1000)


def _say(msg: str, quiet: bool = False) -> None:
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def run_experiment(
    plan: ExperimentPlan,
    out: Path,
    *,
    devices,
    dist: _Dist,
    quiet: bool,
    reuse: bool = True,
) -> dict[str, Any]:
    """Run this process's missing chunks of one experiment.

    With ``reuse``, chunks whose rollouts another experiment in ``out`` has
    already computed (:class:`_Donors`) are copied from there instead.

    Returns the session record for the manifest; raises KeyboardInterrupt after
    saying what was kept.
    """
    d = _exp_dir(out, plan.name)
    chunks_dir = d / "chunks"
    chunks_dir.mkdir(parents=True, exist_ok=True)
    res.clean_stale_tmp(chunks_dir)
    session = {
        "id": f"{socket.gethostname()}-{os.getpid()}-{int(time.time())}",
        "host": socket.gethostname(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "devices": _device_info(devices),
        "process_id": dist.process_id,
        "num_processes": dist.num_processes,
    }
    if dist.leader:
        _write_manifest(plan, d, "running", session)
    mine = [
        c
        for i, c in enumerate(plan.chunks)
        if i % dist.num_processes == dist.process_id
    ]
    _drop_damaged(plan, mine, d)
    todo = [c for c in mine if not res.chunk_done(chunks_dir, c.id)]
    # Work order: objects outer, arms inner, so loaded problems are reused.
    todo.sort(key=lambda c: (c.objects[0], c.trials[0], c.arm))
    git = _git_commit()
    session["git"] = git
    t_session = time.perf_counter()
    computed = reused = 0
    bar = None

    def meta_of(c: Chunk, curve_steps, wall: float, **extra) -> dict[str, Any]:
        return {
            "id": c.id,
            "hash": c.hash,
            "signature": c.signature,
            "experiment": plan.name,
            "arm": plan.arms[c.arm].label,
            "objects": [plan.objects[i].name for i in c.objects],
            "object_stamps": [_object_stamp(plan.objects[i]) for i in c.objects],
            "trials": list(c.trials),
            "rollouts": c.rollouts,
            "curve_steps": curve_steps,
            "wall_s": wall,
            "device": _device_info(devices),
            "host": socket.gethostname(),
            "process_id": dist.process_id,
            "git": git,
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            **extra,
        }

    try:
        if todo and reuse:
            donors = _Donors(out, plan.name, git)
            left, origins = [], set()
            for c in todo:
                t0 = time.perf_counter()
                got = _reuse_chunk(plan, c, donors)
                if got is None:
                    left.append(c)
                    continue
                tables, curve_steps, origin = got
                meta = meta_of(
                    c, curve_steps, time.perf_counter() - t0, reused_from=origin
                )
                res.write_chunk(chunks_dir, c.id, tables, meta)
                origins.update(o.split("/")[0] for o in origin)
                reused += 1
            if reused:
                _say(
                    f"{plan.name}: {reused} chunk(s) copied from identical rollouts "
                    f"of {', '.join(sorted(origins))} (--no-reuse computes them)",
                    quiet,
                )
            todo = left
        done_before = sum(1 for c in plan.chunks if res.chunk_done(chunks_dir, c.id))
        if todo:
            _say(
                f"{plan.name}: {len(todo)} chunk(s) to run ({done_before} of "
                f"{len(plan.chunks)} already done), {sum(c.rollouts for c in todo)} "
                f"rollouts on {len(devices)} {devices[0].device_kind} device(s)",
                quiet,
            )
        bar = _Progress(
            sum(c.work for c in todo),
            sum(c.rollouts for c in todo),
            quiet or not todo,
            plan.name,
        )
        cache = _ProblemCache()
        for c in todo:
            if res.chunk_done(chunks_dir, c.id):  # finished by another process
                bar.skip(c.work)
                continue
            bar.begin_chunk(c.work)
            t0 = time.perf_counter()
            tables, curve_steps = _run_chunk(
                plan, c, cache, devices, _engine_progress(bar, c.rollouts)
            )
            meta = meta_of(c, curve_steps, time.perf_counter() - t0)
            res.write_chunk(chunks_dir, c.id, tables, meta)
            computed += 1
            bar.end_chunk(c.rollouts)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        n_done = sum(1 for c in plan.chunks if res.chunk_done(chunks_dir, c.id))
        session["ended"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        session["wall_s"] = time.perf_counter() - t_session
        session["chunks_computed"] = computed
        session["chunks_reused"] = reused
        if dist.leader:
            _write_manifest(plan, d, "interrupted", session)
        _say(
            f"\ninterrupted: {plan.name} kept {n_done} of {len(plan.chunks)} finished "
            f"chunk(s) in {chunks_dir} ({computed} computed now); the chunk in "
            "flight was dropped. Run the same command again to resume."
        )
        raise
    bar.close()
    session["ended"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    session["wall_s"] = time.perf_counter() - t_session
    session["chunks_computed"] = computed
    session["chunks_reused"] = reused
    return session


def finish_experiment(
    plan: ExperimentPlan, out: Path, session: dict[str, Any], quiet: bool
) -> str:
    """Merge the chunks of a complete experiment into its final tables and write
    the manifest; returns "complete" or "incomplete" (chunks missing)."""
    d = _exp_dir(out, plan.name)
    chunks_dir = d / "chunks"
    _drop_damaged(plan, plan.chunks, d)
    missing = [c.id for c in plan.chunks if not res.chunk_done(chunks_dir, c.id)]
    if missing:
        _write_manifest(plan, d, "incomplete", session)
        _say(
            f"{plan.name}: {len(missing)} chunk(s) of other processes are not in "
            f"{chunks_dir}; copy every host's chunks there and run this command "
            "again without --coordinator to merge",
        )
        return "incomplete"
    counts = _merge(plan, d)
    _write_manifest(plan, d, "complete", session)
    _say(
        f"{plan.name}: complete -> {d} ("
        + ", ".join(f"{k} {v} rows" for k, v in counts.items())
        + ")",
        quiet,
    )
    return "complete"


def _check_user_methods(plans: Sequence[ExperimentPlan], quiet: bool) -> None:
    """Run the conformance checks on every method from outside the package
    (:mod:`legs_jax.methods.conformance`) before any chunk; a failure is a
    one-line error."""
    from legs_jax import methods
    from legs_jax.methods import conformance

    names = {a.method for p in plans for a in p.arms}
    for name in sorted(n for n in names if not methods.builtin(n)):
        _say(f"{name}: conformance checks (jit, jit-vmap, masks, finite)", quiet)
        conformance.check(methods.get(name))


def _print_plan(plan: ExperimentPlan, out: Path) -> None:
    """What the run would do: nothing for a complete experiment (as the run
    decides it), a refusal for another configuration, else the chunks to run."""
    import json

    d = _exp_dir(out, plan.name)
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
    parser = build_parser()
    a = parser.parse_args(argv)
    _validate_args(parser, a)
    _set_device_flags(a.devices)
    out = Path(a.out or ("results/_scratch/smoke" if a.smoke else "results"))
    names = (
        list(EXPERIMENTS)
        if (a.all or (a.smoke and not a.experiment))
        else list(dict.fromkeys(a.experiment))
    )
    started = False
    try:
        import sweeps
        from legs_jax.errors import ConfigError
        from legs_jax.problem import ProblemFileError

        dist = _init_distributed(a)
        devices = _devices(a.devices)
        _compile_cache(a.compile_cache)
        catalog = _catalog()
        a.declared = {m for n in EXPERIMENTS for m, _, _ in sweeps.get(n).ARMS}
        plans = []
        for name in names:
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
                _print_plan(plan, out)
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


if __name__ == "__main__":
    sys.exit(main())
