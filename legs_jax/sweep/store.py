"""The chunk store: output folders, finished chunks (checked by their SHA-256),
reuse of identical rollouts from other experiments, manifests and the merge into
the final tables."""

from __future__ import annotations

import functools
import os
import platform
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from legs_jax import results as res
from legs_jax._files import git_state
from legs_jax._machine import machine
from legs_jax.core import problem as problem_mod
from legs_jax.sweep.plan import Chunk, ExperimentPlan, ObjectEntry, SweepError, _say
from precompute import problemset


def _versions() -> dict[str, str]:
    """Python, the processor and the packages that can change a result's bits."""
    return {"python": platform.python_version(), **machine()}


def _array_digests(o: ObjectEntry) -> dict[str, str]:
    """SHA-256 of each array the engine reads of ``o``'s problem file (recorded in
    the manifest, so that a later run can name the arrays that differ)."""
    return dict(_digests_of(o.path, o.sha256, o.source == "shipped"))


@functools.lru_cache(maxsize=256)
def _digests_of(path: str, sha256: str, shipped: bool) -> tuple[tuple[str, str], ...]:
    if shipped:
        found = problemset.array_digests(Path(path))
        if found is not None:
            return tuple(sorted(found.items()))

    try:
        return tuple(sorted(problem_mod.array_digests(problem_mod.load(path)).items()))
    except (OSError, problem_mod.ProblemFileError):
        return ()


def _objects_differ(old: Mapping[str, Any], plan: ExperimentPlan) -> str:
    """The objects whose problem file differs from the one the results in a
    manifest were made with, and, where both are known, the arrays that differ."""
    files = old.get("problem_files") or {}
    parts = []
    for o in plan.objects:
        rec = files.get(o.name)
        if rec is None or rec.get("sha256") == o.sha256:
            continue
        before = rec.get("arrays") or {}
        now = _array_digests(o) if before else {}
        arrays = sorted(k for k in before if now.get(k) not in (None, before[k]))
        parts.append(f"{o.name} ({', '.join(arrays)})" if arrays else o.name)
    if not parts:
        return ""
    more = f" and {len(parts) - 8} more" if len(parts) > 8 else ""
    return (
        f"; the problem files of {len(parts)} object(s) differ from those the "
        f"results were made with: {', '.join(parts[:8])}{more}"
    )


def _portable_path(path: str | os.PathLike) -> str:
    """``path`` relative to the working directory or to the repository when it lies
    under one of them (so results name no machine-specific folder), else as
    given."""
    p = Path(path).resolve()
    for base in (Path.cwd().resolve(), Path(__file__).resolve().parents[2]):
        try:
            return p.relative_to(base).as_posix()
        except ValueError:
            continue
    return str(path)


def _git_commit() -> dict[str, Any]:
    """The commit of the code and whether tracked files other than ``results/``
    (which a sweep rewrites) differ from it."""
    return git_state()


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


def donor_keys(plan: ExperimentPlan, chunk: Chunk) -> list[tuple] | None:
    """The keys under which a chunk's rollouts can come from another experiment's
    chunk (:class:`_Donors`): one per (object, trial) pair; None for a chunk that
    is always computed (no signature, or it records active sets, which no
    experiment records twice)."""
    if chunk.record_active_set or not chunk.signature:
        return None
    return [
        (chunk.signature, _object_stamp(plan.objects[i]), t)
        for i in chunk.objects
        for t in chunk.trials
    ]


def _reuse_chunk(plan: ExperimentPlan, chunk: Chunk, donors: _Donors):
    """The tables of ``chunk`` copied from donor chunks that hold every one of its
    (object, trial) pairs, or None when some pair has no donor. Chunks that record
    active sets are always computed (no experiment records them twice)."""
    import json

    import pandas as pd

    keys = donor_keys(plan, chunk)
    if keys is None or not donors:
        return None
    sources: dict[Path, None] = {}
    for key in keys:
        d = donors.find(*key)
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
                f"{diff}){_objects_differ(old, plan)}; pass --overwrite to replace "
                "them or --out for another folder"
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


def _manifest(d: Path) -> dict[str, Any] | None:
    """The manifest of the experiment folder ``d``; None where it is missing or
    unreadable."""
    import json

    try:
        with open(d / "manifest.json") as fh:
            return json.load(fh)
    except (OSError, json.JSONDecodeError):
        return None


def _merged_without_chunks(plan: ExperimentPlan, out: Path) -> bool:
    """The experiment's merged tables are complete and current (same problem
    files; :func:`_prepare_dir` has already refused another configuration) but
    some chunk folders are gone, as in a fresh clone of committed results:
    nothing needs recomputing."""
    d = _exp_dir(out, plan.name)
    chunks_dir = d / "chunks"
    if all(res.chunk_done(chunks_dir, c.id) for c in plan.chunks):
        return False  # the ordinary path re-merges from the chunks
    old = _manifest(d)
    if old is None:
        return False
    files = old.get("problem_files") or {}
    return (
        old.get("status") == "complete"
        and _damaged_tables(d, old) is None
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
    d = _exp_dir(out, plan.name)
    old = _manifest(d)
    if old is None:
        return False
    return (
        old.get("status") == "complete"
        and old.get("config_hash") == res.config_hash(plan.config())
        and _damaged_tables(d, old) is None
        and all(_chunk_ok(d / "chunks", c.id) for c in plan.chunks)
    )


def _damaged_tables(d: Path, manifest: Mapping[str, Any]) -> str | None:
    """Why the merged tables of a complete experiment in ``d`` cannot be trusted
    (a table missing, or not the file the merge wrote: its SHA-256 is in the
    manifest's ``tables``), or None when they are whole. A manifest written
    before the tables' hashes were recorded is checked by reading each table's
    parquet footer."""
    recorded = manifest.get("tables")
    if not isinstance(recorded, Mapping):
        import pyarrow.parquet as pq

        recorded = {"runs.parquet": None} | {
            f"{t}.parquet": None
            for t in _FINAL_TABLES
            if (d / f"{t}.parquet").is_file()
        }
        for name in recorded:
            try:
                pq.read_metadata(d / name)
            except (OSError, ValueError) as e:
                return f"{name} cannot be read: {str(e).splitlines()[0][:80]}"
        return None
    if "runs.parquet" not in recorded:
        return "runs.parquet is not recorded in the manifest"
    for name, sha in recorded.items():
        if not (d / name).is_file():
            return f"{name} is missing"
        if res.sha256_file(d / name) != sha:
            return f"{name} does not match its SHA-256 in the manifest"
    return None


def _warn_damaged_tables(plan: ExperimentPlan, out: Path) -> str | None:
    """Name the damaged merged tables of a complete experiment in a warning (they
    are then merged again from the chunks, or the chunks computed again where
    they are gone); returns the reason, or None."""
    d = _exp_dir(out, plan.name)
    old = _manifest(d)
    if old is None or old.get("status") != "complete":
        return None
    why = _damaged_tables(d, old)
    if why is not None:
        _say(
            f"warning: {plan.name}: the merged tables in {d} are damaged ({why}); "
            "merging them again (chunks that are gone are computed again)"
        )
    return why


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
                    "compile_s",
                    "run_s",
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
            o.name: {
                "path": _portable_path(o.path),
                "sha256": o.sha256,
                "prior": o.prior,
                "source": o.source,
                "arrays": _array_digests(o),
            }
            for o in plan.objects
        },
        "priors": sorted({o.prior for o in plan.objects}),
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
        "compile_s_chunks": float(
            sum(c.get("compile_s") or 0.0 for c in chunks.values())
        ),
        "sessions": sessions,
        "curves": "aggregated: mean and standard error over the T x R runs of each "
        "object, method, variant and hyperparameters; per-run curves are in the "
        "gap_curve column of chunks/*/runs.parquet",
        "extra": plan.extra,
    }
    if status == "complete":  # the merged tables' SHA-256, checked on every run
        manifest["tables"] = {
            f"{t}.parquet": res.sha256_file(d / f"{t}.parquet")
            for t in _FINAL_TABLES
            if (d / f"{t}.parquet").is_file()
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
