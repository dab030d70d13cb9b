"""Tidy result tables, chunk files and manifests of a sweep.

A sweep writes one folder per experiment::

    <out>/<experiment>/
        manifest.json          configuration, seeds, versions, devices, timings
        runs.parquet           one row per run (final values)
        curves.parquet         gap every ``record_every`` steps, mean and SE over runs
        checks.parquet         one row per Dirichlet check (recorded methods only)
        active_set.parquet     LEGS active sets, trial 0 / rollout 0 (case study)
        grasps.parquet         trial 0's reservoirs (case study, for the histograms)
        objects.parquet        one row per object: set, id, poses, problem hash
        chunks/<chunk id>/     the raw tables of each finished chunk

Schemas (hyperparameter columns: s, prior_offset, delta, gamma, epsilon, eta as
float64; k, n as int64; ``variant`` is "" for the default configuration):

- runs: experiment, set, object, method, variant, trial, rollout, seed,
  <hyperparameters>, horizon, final_gap, final_performance (float64), successes,
  distinct_grasps, replacements (int64). One row per run.
- curves: experiment, set, object, method, variant, <hyperparameters>, step,
  gap_mean, gap_se, n_runs. Aggregated over the T x R runs of each (object,
  method, variant, hyperparameters): mean and standard error (sample standard
  deviation / sqrt(n_runs)) at steps 0, record_every, ..., H. Per-run curves are
  kept in the ``gap_curve`` column of ``chunks/*/runs.parquet``.
- checks: experiment, set, object, method, variant, trial, rollout,
  <hyperparameters>, step, p_lower (p-hat* over all candidates, the paper's bound),
  p_lower_attempted (over attempted grasps only), p_lower_eb (our bound, the
  Dirichlet bound on an empirical-Bayes posterior of the recommended grasps,
  legs_jax.core.stopping; NaN for methods without per-grasp counts),
  true_performance, after_failure (mean attempts after a failed attempt at a
  landing until the next success with the recommendations frozen: what verified
  stopping spends between two samples of its test, legs_jax.core.verify; absent
  from results made before it was recorded).
- active_set: object, method, variant, grid_index, trial, rollout, step, pose,
  slot, grasp, robustness (filled slots of visited poses only).
- grasps: object, trial, pose, grasp, landing, robustness, prior (trial 0).
- objects: object, set, object_id, num_poses, num_grasps, problem_file, sha256.

A chunk is written into a temporary folder which is then renamed into place, so a
chunk folder exists only when complete. The final tables are merged from the chunk
folders in a fixed order, so they do not depend on how often the sweep was
interrupted, on the device count or on the order in which chunks finished.

Dimension letters: G grid points, O objects, T trials, R rollouts, C1 curve points,
C2 checks, P poses, k active-set slots.

Why one file: it owns the layout of a results folder from end to end. The chunk
tables, the chunk folders and the merge read the same column lists, file names and
metadata, so they change together.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from legs_jax._files import atomic_write, sha256_file

__all__ = [
    "CHUNK_META",
    "hparam_columns",
    "integer_hparams",
    "ChunkContext",
    "atomic_write_json",
    "atomic_write_parquet",
    "chunk_done",
    "chunk_tables",
    "config_hash",
    "merge_chunks",
    "read_chunk_meta",
    "sha256_file",
    "verify_chunk",
    "write_chunk",
]


@functools.cache
def hparam_columns() -> tuple[str, ...]:
    """The hyperparameter columns, in this order, of every table that carries
    them: those this package's methods declare
    (:func:`legs_jax.core.methods.column_defaults`)."""
    from legs_jax.core import methods  # jax: kept out of reading and writing tables

    return tuple(methods.column_defaults())


@functools.cache
def integer_hparams() -> frozenset[str]:
    """The hyperparameters a method of this package declares integer (their
    columns are int64, the others float64)."""
    from legs_jax.core import methods  # jax: kept out of reading and writing tables

    return frozenset(
        name
        for m in methods.names()
        if methods.builtin(m)
        for name, rng in methods.get(m).ranges.items()
        if rng.integer
    )


CHUNK_META = "chunk.json"
# Tables a chunk folder may hold; "runs" is always there.
_CHUNK_TABLES = ("runs", "checks", "active_set")


# ------------------------------------------------------------------------ hashing
def _canonical(obj: Any) -> Any:
    """JSON-able, order-stable form of ``obj`` (tuples become lists, NumPy scalars
    become Python numbers)."""
    if isinstance(obj, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(obj.items())}
    if isinstance(obj, list | tuple):
        return [_canonical(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def config_hash(config: Mapping[str, Any]) -> str:
    """sha256 of the canonical JSON of ``config``."""
    text = json.dumps(_canonical(config), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


# -------------------------------------------------------------------- atomic I/O
def atomic_write_parquet(df: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write ``df`` (without its index) to ``path`` through a temporary file."""
    table = pa.Table.from_pandas(df, preserve_index=False)
    return atomic_write(path, lambda fh: pq.write_table(table, fh))


def atomic_write_json(obj: Any, path: str | os.PathLike) -> Path:
    def write(fh) -> None:
        json.dump(_canonical(obj), fh, indent=1, sort_keys=True)
        fh.write("\n")

    return atomic_write(path, write, text=True)


# -------------------------------------------------------------------- chunk tables
class ChunkContext:
    """What a chunk's rows need besides the engine's arrays.

    Args:
      experiment: experiment name.
      method, variant: the arm.
      grid: G full hyperparameter dicts (every key of :func:`hparam_columns`).
      objects: O (name, set) pairs, in batch order.
      trials: T absolute trial indices, in batch order.
      rollouts: R absolute rollout indices.
      seed, horizon: recorded on every run row.
      record_checks: write checks rows.
      record_active_set: write active-set rows (trial 0, rollout 0 only).
      robustness: [O, T, P, K] ground truth of the batch (for active-set rows).
    """

    def __init__(
        self,
        *,
        experiment: str,
        method: str,
        variant: str,
        grid: Sequence[Mapping[str, float]],
        objects: Sequence[tuple[str, str]],
        trials: Sequence[int],
        rollouts: Sequence[int],
        seed: int,
        horizon: int,
        record_checks: bool,
        record_active_set: bool = False,
        robustness: np.ndarray | None = None,
    ):
        self.experiment = experiment
        self.method = method
        self.variant = variant
        self.grid = [dict(g) for g in grid]
        self.objects = [tuple(o) for o in objects]
        self.trials = [int(t) for t in trials]
        self.rollouts = [int(r) for r in rollouts]
        self.seed = int(seed)
        self.horizon = int(horizon)
        self.record_checks = record_checks
        self.record_active_set = record_active_set
        self.robustness = robustness
        for g in self.grid:
            missing = [c for c in hparam_columns() if c not in g]
            if missing:
                raise ValueError(f"grid point lacks hyperparameters {missing}")


def _expand(ctx: ChunkContext, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """Index columns of a [G, O, T, R, ...] array flattened in C order."""
    G, O, T, R = shape[:4]  # noqa: E741
    if (G, O, T, R) != (
        len(ctx.grid),
        len(ctx.objects),
        len(ctx.trials),
        len(ctx.rollouts),
    ):
        raise ValueError(
            f"result shape {shape[:4]} does not match the chunk's "
            f"[G={len(ctx.grid)}, O={len(ctx.objects)}, T={len(ctx.trials)}, "
            f"R={len(ctx.rollouts)}]"
        )
    idx = np.indices(shape).reshape(len(shape), -1)
    return {"g": idx[0], "o": idx[1], "t": idx[2], "r": idx[3], "rest": idx[4:]}


def _label_columns(ctx: ChunkContext, ix: dict[str, np.ndarray]) -> dict[str, Any]:
    names = np.array([o[0] for o in ctx.objects], dtype=object)
    sets = np.array([o[1] for o in ctx.objects], dtype=object)
    cols: dict[str, Any] = {
        "experiment": ctx.experiment,
        "set": sets[ix["o"]],
        "object": names[ix["o"]],
        "method": ctx.method,
        "variant": ctx.variant,
    }
    return cols


def _hparam_columns(ctx: ChunkContext, g: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`hparam_columns`, then any other hyperparameter of the method (a
    user's method's own, float64) in name order."""
    extra = sorted(set(ctx.grid[0]) - set(hparam_columns()))
    cols = {}
    for c in (*hparam_columns(), *extra):
        dtype = np.int64 if c in integer_hparams() else np.float64
        vals = np.array([gp[c] for gp in ctx.grid], dtype=dtype)
        cols[c] = vals[g]
    return cols


def _with_extra(columns: Sequence[str], df: pd.DataFrame) -> list[str]:
    """``columns`` with the extra hyperparameter columns of ``df`` (those of a
    user's method, :func:`_hparam_columns`) after :func:`hparam_columns`."""
    known = {*_run_columns(), *_check_columns(), *_INTERNAL_COLUMNS}
    extra = sorted(c for c in df.columns if c not in known)
    at = list(columns).index(hparam_columns()[-1]) + 1
    return [*columns[:at], *extra, *columns[at:]]


def _frame(cols: dict[str, Any], n: int) -> pd.DataFrame:
    out = {}
    for k, v in cols.items():
        if isinstance(v, np.ndarray):
            out[k] = v
        else:
            out[k] = np.full(n, v, dtype=object if isinstance(v, str) else None)
    df = pd.DataFrame(out)
    for k in ("experiment", "set", "object", "method", "variant"):
        if k in df:
            df[k] = df[k].astype(str)
    return df


def chunk_tables(result: Any, ctx: ChunkContext) -> dict[str, pd.DataFrame]:
    """Tidy tables of one engine result (a ``RunResult``) with leading [G, O, T, R].

    ``runs`` has one row per run and a ``gap_curve`` list column (the run's gap at
    ``curve_steps``); ``checks`` one row per Dirichlet check when
    ``ctx.record_checks``; ``active_set`` one row per filled active-set slot of
    trial 0 / rollout 0 when ``ctx.record_active_set``.
    """
    final_gap = np.asarray(result.final_gap)
    ix = _expand(ctx, final_gap.shape)
    n = final_gap.size
    trials = np.array(ctx.trials, np.int64)
    rollouts = np.array(ctx.rollouts, np.int64)
    cols = _label_columns(ctx, ix)
    cols["trial"] = trials[ix["t"]]
    cols["rollout"] = rollouts[ix["r"]]
    cols["seed"] = np.full(n, ctx.seed, np.int64)
    cols.update(_hparam_columns(ctx, ix["g"]))
    cols["horizon"] = np.full(n, ctx.horizon, np.int64)
    cols["final_gap"] = final_gap.reshape(-1).astype(np.float64)
    cols["final_performance"] = (
        np.asarray(result.final_performance).reshape(-1).astype(np.float64)
    )
    for c in ("successes", "distinct_grasps", "replacements"):
        cols[c] = np.asarray(getattr(result, c)).reshape(-1).astype(np.int64)
    cols["grid_index"] = ix["g"].astype(np.int64)
    gap_curve = np.asarray(result.gap_curve, np.float32)
    c1 = gap_curve.shape[-1]
    runs = _frame(cols, n)
    runs["gap_curve"] = pd.Series(list(gap_curve.reshape(n, c1)), dtype=object)
    tables = {"runs": runs}

    if ctx.record_checks:
        p_lower = np.asarray(result.check_p_lower)
        steps = np.asarray(result.check_steps, np.int64)
        ix = _expand(ctx, p_lower.shape)
        m = p_lower.size
        cols = _label_columns(ctx, ix)
        cols["trial"] = trials[ix["t"]]
        cols["rollout"] = rollouts[ix["r"]]
        cols.update(_hparam_columns(ctx, ix["g"]))
        cols["step"] = steps[ix["rest"][0]] if m else np.zeros(0, np.int64)
        cols["p_lower"] = p_lower.reshape(-1).astype(np.float64)

        def column(field: str) -> np.ndarray:
            """A check field flattened to float64, NaN where the run lacks it."""
            x = getattr(result, field, None)
            if x is None:
                return np.full(m, np.nan)
            return np.asarray(x).reshape(-1).astype(np.float64)

        cols["p_lower_attempted"] = column("check_p_lower_attempted")
        cols["p_lower_eb"] = column("check_p_lower_eb")
        cols["true_performance"] = column("check_true_performance")
        cols["after_failure"] = column("check_after_failure")
        cols["grid_index"] = ix["g"].astype(np.int64)
        tables["checks"] = _frame(cols, m)

    if ctx.record_active_set:
        tables["active_set"] = _active_set_rows(result, ctx)
    return tables


def _active_set_rows(result: Any, ctx: ChunkContext) -> pd.DataFrame:
    """Filled active-set slots of trial 0, rollout 0 of each object and grid point."""
    columns = [
        "object",
        "method",
        "variant",
        "grid_index",
        "trial",
        "rollout",
        "step",
        "pose",
        "slot",
        "grasp",
        "robustness",
    ]
    if (
        result.active_set is None
        or 0 not in ctx.trials
        or 0 not in ctx.rollouts
        or ctx.robustness is None
    ):
        return pd.DataFrame({c: [] for c in columns})
    act = np.asarray(result.active_set)  # [G, O, T, R, C2, P, k]
    t, r = ctx.trials.index(0), ctx.rollouts.index(0)
    steps = np.asarray(result.check_steps, np.int64)
    frames = []
    for g in range(act.shape[0]):
        for o, (name, _) in enumerate(ctx.objects):
            a = act[g, o, t, r]  # [C2, P, k]
            c, p, slot = np.nonzero(a >= 0)
            grasp = a[c, p, slot].astype(np.int64)
            rob = ctx.robustness[o, t][p, grasp].astype(np.float64)
            frames.append(
                pd.DataFrame(
                    {
                        "object": np.full(len(c), name, dtype=object),
                        "method": ctx.method,
                        "variant": ctx.variant,
                        "grid_index": np.full(len(c), g, np.int64),
                        "trial": np.zeros(len(c), np.int64),
                        "rollout": np.zeros(len(c), np.int64),
                        "step": steps[c],
                        "pose": p.astype(np.int64),
                        "slot": slot.astype(np.int64),
                        "grasp": grasp,
                        "robustness": rob,
                    }
                )
            )
    return pd.concat(frames, ignore_index=True)


# ------------------------------------------------------------------- chunk folders
def _tmp_name(chunk_id: str) -> str:
    return f".tmp-{chunk_id}-{socket.gethostname()}-{os.getpid()}"


def write_chunk(
    chunks_dir: str | os.PathLike,
    chunk_id: str,
    tables: Mapping[str, pd.DataFrame],
    meta: Mapping[str, Any],
) -> bool:
    """Write a finished chunk atomically: tables and ``chunk.json`` into a temporary
    folder, then rename it to ``chunks_dir/chunk_id``. ``chunk.json`` records the
    SHA-256 of every table file (``files``), which :func:`verify_chunk` checks.

    Returns False (and writes nothing) when another process finished the same
    chunk first.
    """
    chunks_dir = Path(chunks_dir)
    chunks_dir.mkdir(parents=True, exist_ok=True)
    final = chunks_dir / chunk_id
    tmp = chunks_dir / _tmp_name(chunk_id)
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        files = {}
        for name, df in tables.items():
            atomic_write_parquet(df, tmp / f"{name}.parquet")
            files[f"{name}.parquet"] = sha256_file(tmp / f"{name}.parquet")
        atomic_write_json({**meta, "files": files}, tmp / CHUNK_META)
        for f in tmp.iterdir():
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
        try:
            os.rename(tmp, final)
        except OSError:
            if chunk_done(chunks_dir, chunk_id):
                shutil.rmtree(tmp)
                return False
            raise
    except BaseException:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    return True


def chunk_done(chunks_dir: str | os.PathLike, chunk_id: str) -> bool:
    return (Path(chunks_dir) / chunk_id / CHUNK_META).is_file()


def verify_chunk(chunks_dir: str | os.PathLike, chunk_id: str) -> str | None:
    """What is wrong with a finished chunk, or None when it is whole: its
    ``chunk.json`` must parse and every table file it lists must have the SHA-256
    it records (a chunk written before checksums were recorded must at least have
    readable parquet files)."""
    d = Path(chunks_dir) / chunk_id
    try:
        meta = read_chunk_meta(chunks_dir, chunk_id)
    except (OSError, ValueError):
        return f"{CHUNK_META} is unreadable"
    files = meta.get("files")
    if not isinstance(files, dict):
        for f in sorted(d.glob("*.parquet")):
            try:
                pq.read_metadata(f)
            except Exception:  # noqa: BLE001 - any failure to read is damage
                return f"{f.name} is unreadable"
        return None if (d / "runs.parquet").is_file() else "runs.parquet is missing"
    for name, digest in sorted(files.items()):
        f = d / name
        if not f.is_file():
            return f"{name} is missing"
        if sha256_file(f) != digest:
            return f"{name} does not match its SHA-256 in {CHUNK_META}"
    return None


def read_chunk_meta(chunks_dir: str | os.PathLike, chunk_id: str) -> dict[str, Any]:
    with open(Path(chunks_dir) / chunk_id / CHUNK_META) as fh:
        return json.load(fh)


def clean_stale_tmp(chunks_dir: str | os.PathLike) -> list[str]:
    """Remove temporary chunk folders left by killed processes of this host."""
    chunks_dir = Path(chunks_dir)
    removed = []
    if not chunks_dir.is_dir():
        return removed
    host = socket.gethostname()
    for d in chunks_dir.glob(".tmp-*"):
        head, _, pid = d.name.rpartition("-")
        if not head.endswith("-" + host) or not pid.isdigit():
            continue
        if int(pid) != os.getpid() and _pid_alive(int(pid)):
            continue
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d.name)
    return removed


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# -------------------------------------------------------------------------- merge
_ARM_COLUMNS = ["experiment", "set", "object", "method", "variant"]
_RUN_RESULTS = [
    "horizon",
    "final_gap",
    "final_performance",
    "successes",
    "distinct_grasps",
    "replacements",
]
_CHECK_RESULTS = [
    "step",
    "p_lower",
    "p_lower_attempted",
    "p_lower_eb",
    "true_performance",
]


def run_columns_besides_hparams() -> frozenset[str]:
    """The columns of ``runs.parquet`` that are not a hyperparameter: what names
    a run and what it measured (every other column is a method's hyperparameter,
    a user's method's included)."""
    return frozenset([*_ARM_COLUMNS, "trial", "rollout", "seed", *_RUN_RESULTS])


def _run_columns() -> list[str]:
    return [*_ARM_COLUMNS, "trial", "rollout", "seed", *hparam_columns(), *_RUN_RESULTS]


def _group_columns() -> list[str]:
    return [*_ARM_COLUMNS, *hparam_columns()]


def _check_columns() -> list[str]:
    return [*_ARM_COLUMNS, "trial", "rollout", *hparam_columns(), *_CHECK_RESULTS]


# Columns of the chunk tables that the merged tables drop or keep elsewhere.
_INTERNAL_COLUMNS = ("grid_index", "gap_curve")


def _read(path: Path) -> pd.DataFrame:
    return pq.read_table(path).to_pandas()


def merge_chunks(
    chunks_dir: str | os.PathLike,
    chunk_ids: Sequence[str],
    arm_order: Sequence[tuple[str, str]],
    object_order: Sequence[str],
) -> dict[str, pd.DataFrame]:
    """Final tables of an experiment from its chunk folders.

    Rows are sorted by arm (``arm_order`` of (method, variant)), grid point, object
    (``object_order``), trial, rollout (and step), so the result does not depend on
    how the work was chunked. ``curves`` aggregates each (object, arm, grid point)
    over its T x R runs: ``gap_mean``, ``gap_se`` (sample standard deviation / sqrt
    of ``n_runs``; NaN for a single run) at every recorded step.
    """
    chunks_dir = Path(chunks_dir)
    arm_rank = {a: i for i, a in enumerate(arm_order)}
    obj_rank = {o: i for i, o in enumerate(object_order)}
    parts: dict[str, list[pd.DataFrame]] = {t: [] for t in _CHUNK_TABLES}
    curve_steps = None
    for cid in chunk_ids:
        meta = read_chunk_meta(chunks_dir, cid)
        steps = list(meta["curve_steps"])
        if curve_steps is None:
            curve_steps = steps
        elif steps != curve_steps:
            raise ValueError(f"chunk {cid}: curve steps differ from other chunks")
        for t in _CHUNK_TABLES:
            f = chunks_dir / cid / f"{t}.parquet"
            if f.is_file():
                parts[t].append(_read(f))

    def order(df: pd.DataFrame, extra: Sequence[str]) -> pd.DataFrame:
        if df.empty:
            return df.reset_index(drop=True)
        key = pd.DataFrame(
            {
                "_arm": [
                    arm_rank[(m, v)]
                    for m, v in zip(df["method"], df["variant"], strict=True)
                ],
                "_g": df["grid_index"].to_numpy(),
                "_o": df["object"].map(obj_rank).to_numpy(),
            }
        )
        for c in extra:
            key[c] = df[c].to_numpy()
        idx = np.lexsort([key[c].to_numpy() for c in reversed(key.columns)])
        return df.iloc[idx].reset_index(drop=True)

    runs = order(pd.concat(parts["runs"], ignore_index=True), ["trial", "rollout"])
    curves = _aggregate_curves(runs, np.asarray(curve_steps or [], np.int64))
    out = {
        "runs": runs[_with_extra(_run_columns(), runs)].reset_index(drop=True),
        "curves": curves,
    }
    if parts["checks"]:
        checks = order(
            pd.concat(parts["checks"], ignore_index=True), ["trial", "rollout", "step"]
        )
        out["checks"] = checks[_with_extra(_check_columns(), checks)].reset_index(
            drop=True
        )
    else:
        out["checks"] = pd.DataFrame({c: [] for c in _check_columns()})
    if parts["active_set"]:
        act = pd.concat(parts["active_set"], ignore_index=True)
        out["active_set"] = order(act, ["step", "pose", "slot"])
    return out


def _aggregate_curves(runs: pd.DataFrame, steps: np.ndarray) -> pd.DataFrame:
    group = _with_extra(_group_columns(), runs)
    columns = [*group, "step", "gap_mean", "gap_se", "n_runs"]
    if runs.empty:
        return pd.DataFrame({c: [] for c in columns})
    # The arm and its grid point fix every hyperparameter (NaN in a column that
    # only a user's method has would never compare equal).
    keys = runs[[*_ARM_COLUMNS, "grid_index"]]
    # Runs are sorted, so each group is one contiguous block.
    change = np.ones(len(runs), bool)
    change[1:] = (keys.iloc[1:].to_numpy() != keys.iloc[:-1].to_numpy()).any(axis=1)
    starts = np.flatnonzero(change)
    ends = np.append(starts[1:], len(runs))
    frames = []
    curves = runs["gap_curve"].to_numpy()
    for a, b in zip(starts, ends, strict=True):
        block = np.stack(curves[a:b]).astype(np.float64)  # [N, C1]
        n = block.shape[0]
        mean = block.mean(axis=0)
        se = (
            block.std(axis=0, ddof=1) / np.sqrt(n)
            if n > 1
            else np.full_like(mean, np.nan)
        )
        head = {c: runs[c].iloc[a] for c in group}
        frame = pd.DataFrame({c: [v] * len(steps) for c, v in head.items()})
        frame["step"] = steps
        frame["gap_mean"] = mean
        frame["gap_se"] = se
        frame["n_runs"] = np.full(len(steps), n, np.int64)
        frames.append(frame)
    out = pd.concat(frames, ignore_index=True)
    for c in hparam_columns():
        out[c] = out[c].astype(np.int64 if c in integer_hparams() else np.float64)
    return out[columns]
