"""Plans: arms (a method with its hyperparameter grid), chunks and their cost
model, and the configuration every result depends on."""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
import sys
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from legs_jax import results as res
from legs_jax.core.sampler_versions import SAMPLER_VERSION
from legs_jax.errors import ConfigError

# 2: checks carry p_lower_eb (our stopping bound); 3: checks carry after_failure
# (what verified stopping spends after a failed attempt) and the Thompson methods
# draw with Cheng's Beta sampler (the configuration names it)
RESULTS_VERSION = 3

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
    prior: str = "unknown"  # the prior q the file carries (problem.prior_kind)
    # where the file comes from: "shipped" (data/problemset), "built" (made from
    # the meshes on this machine), "user" (--problems) or "smoke"
    source: str = "built"


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
    # (object-trial pairs, rollouts) of the largest chunk of its arm and padded
    # shape: the engine pads this chunk's program shapes to it, so that they
    # share one compiled program (results do not depend on it).
    shape_of: tuple[int, int] = (0, 0)
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
            "beta_sampler": SAMPLER_VERSION,
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
    from legs_jax.core import methods  # jax: not at sweep start-up

    try:
        return methods.resolve(spec)
    except ConfigError as e:
        raise SweepError(str(e)) from None


def make_arm(method: str, variant: str, hparams: Mapping[str, Any]) -> Arm:
    """Resolve a declared arm: scalars and equal-length sequences (a grid, zipped),
    validated by the method's own declaration
    (:func:`legs_jax.core.methods.parse_grid`).
    Every grid point holds every hyperparameter column of the results (the
    method's values, and :func:`legs_jax.core.methods.column_defaults` for the
    columns it does not have)."""
    from legs_jax.core import methods  # jax: not at sweep start-up

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
# Pose-count buckets: every problem is padded to the first that holds its poses
# (a multiple of the last beyond it), so that a method compiles one program per
# bucket for the whole sweep. Padded poses are masked and their Dirichlet draws
# are keyed by pose, so padding changes no result; it costs the checks' draws of
# the padded poses. Chosen from the catalogue: `python -m legs_jax.sweep.shapes`
# prints the programs and the padded work of several choices (BENCHMARKS.md,
# "Fixed costs").
POSE_BUCKETS = (8, 16, 32)


def pose_bucket(p: int, buckets: Sequence[int] | None = POSE_BUCKETS) -> int:
    """The padded pose count of a problem with ``p`` poses under ``buckets`` (the
    smallest that holds it, past the last its multiples; None: powers of two;
    empty: no padding, every pose count its own)."""
    if buckets is None:
        return 1 << max(0, (p - 1).bit_length())
    if not buckets:
        return p
    for b in buckets:
        if p <= b:
            return b
    last = buckets[-1]
    return -(-p // last) * last


def _pose_bucket(p: int) -> int:
    """The padded pose count of a problem with ``p`` poses (the adopted buckets)."""
    return pose_bucket(p)


def _static_config(arm: Arm, P: int, K: int):
    """The arm's method and its static configuration (that of its first grid
    point) on problems of P poses and K grasps."""
    from legs_jax.core.methods.base import Config  # jax: not at sweep start-up

    m = _method(arm.method)
    point = dict(arm.grid[0])
    return m, Config(num_poses=P, num_grasps=K, **{n: point[n] for n in m.static})


def _rollout_work(arm: Arm, P: int, K: int, horizon: int, check_every: int) -> float:
    """Cost model: the candidate grasps a step touches (the method's declared
    ``cost``; about one exact Beta draw each) plus a fixed cost a step, and the
    Dirichlet checks."""
    m, cfg = _static_config(arm, P, K)
    steps = horizon * (m.card.cost(cfg) + 32.0)
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
    buckets: Sequence[int] | None = POSE_BUCKETS,
) -> list[Chunk]:
    """Split an experiment into chunks, deterministically from its configuration.

    Objects of an arm are grouped by padded shape (pose bucket, K) in catalogue
    order; a chunk holds whole objects while they fit the budgets, else one object
    and an equal-sized block of its trials. ``buckets``: the pose buckets
    (:func:`pose_bucket`; the adopted ones unless a study of others asks).
    """
    chunks: list[Chunk] = []
    for a, arm in enumerate(cfg.arms):
        G = len(arm.grid)
        record_checks = arm.method in cfg.check_methods
        record_act = arm.method in cfg.active_set_methods
        groups: OrderedDict[tuple[int, int], list[int]] = OrderedDict()
        for i, o in enumerate(cfg.objects):
            P = pose_bucket(o.num_poses, buckets)
            groups.setdefault((P, o.num_grasps), []).append(i)
        for (P, K), members in groups.items():
            every = cfg.check_every if record_checks else 0
            w = _rollout_work(arm, P, K, cfg.horizon, every)
            width = 0  # slots of a recorded active set
            if record_act:
                m, static_cfg = _static_config(arm, P, K)
                width = int(m.active_width(static_cfg))
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
    largest: dict[tuple[int, int, int], tuple[int, int]] = {}
    for c in chunks:
        k = (c.arm, c.num_poses, c.num_grasps)
        pairs = len(c.objects) * len(c.trials)
        old = largest.get(k, (0, 0))
        largest[k] = (max(old[0], pairs), max(old[1], c.rollouts))
    chunks = [
        dataclasses.replace(c, shape_of=largest[(c.arm, c.num_poses, c.num_grasps)])
        for c in chunks
    ]
    ids = [c.id for c in chunks]
    if len(set(ids)) != len(ids):  # pragma: no cover - names are unique per plan
        raise SweepError("internal error: duplicate chunk ids")
    return chunks


def _check_plan(plan: ExperimentPlan) -> None:
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


def _say(msg: str, quiet: bool = False) -> None:
    if not quiet:
        print(msg, file=sys.stderr, flush=True)
