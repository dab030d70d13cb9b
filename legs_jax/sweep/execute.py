"""Running an experiment's chunks on the engine, with progress, interruption and
the final merge."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from legs_jax import results as res
from legs_jax.core import problem as problem_mod
from legs_jax.sweep import store
from legs_jax.sweep.hosts import _device_info, _Dist
from legs_jax.sweep.plan import Chunk, ExperimentPlan, _say
from legs_jax.sweep.store import (
    _Donors,
    _drop_damaged,
    _exp_dir,
    _merge,
    _object_stamp,
    _reuse_chunk,
    _write_manifest,
)


# ====================================================================== execution
def _engine():
    """The runtime that runs rollouts (:mod:`legs_jax.runtime`; imported late: JAX
    must start after the device flags are set)."""
    from legs_jax import runtime  # jax: not at sweep start-up

    return runtime


class _ProblemCache:
    """Loaded problems, least recently used first out."""

    def __init__(self, capacity: int = 16):
        self.capacity = capacity
        self._items: OrderedDict[str, Any] = OrderedDict()

    def get(self, path: str):
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
        shape_of=chunk.shape_of,
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


class _Progress:
    """tqdm bar over estimated work (the planner's cost model), showing rollouts
    per second and the ETA: the work left at the rate measured so far."""

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
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}, ETA {remaining}"
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


# Ctrl-C: Python raises KeyboardInterrupt wherever the main thread is, and one
# raised inside a garbage-collection callback or a __del__ (JAX runs such
# callbacks) is printed and swallowed, so the sweep would run on. The handler also
# records the signal, and the loop checks it at every mini-batch and chunk.
_INTERRUPTED = threading.Event()


_SWALLOWING = {"_xla_gc_callback", "__del__"}  # where an exception is swallowed


def _on_sigint(signum, frame) -> None:
    _INTERRUPTED.set()
    f = frame
    while f is not None:
        if f.f_code.co_name in _SWALLOWING:
            return  # the loop's next check raises it, with no warning printed
        f = f.f_back
    raise KeyboardInterrupt


def _check_interrupt() -> None:
    if _INTERRUPTED.is_set():
        raise KeyboardInterrupt


def _engine_progress(bar: _Progress, rollouts: int) -> Callable[[int], None]:
    """The engine reports the number of rollouts done after each mini-batch."""

    def cb(done: int) -> None:
        _check_interrupt()
        bar.fraction(done / max(rollouts, 1))

    return cb


# ------------------------------------------------------------------ output folders


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
    git = store._git_commit()
    session["git"] = git
    t_session = time.perf_counter()
    computed = reused = 0
    compile_total = 0.0
    bar = None

    def close_session() -> None:
        session.update(
            ended=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            wall_s=time.perf_counter() - t_session,
            chunks_computed=computed,
            chunks_reused=reused,
            compile_s=compile_total,
        )

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
            _check_interrupt()
            if res.chunk_done(chunks_dir, c.id):  # finished by another process
                bar.skip(c.work)
                continue
            bar.begin_chunk(c.work)
            t0 = time.perf_counter()
            c0 = _engine().compile_seconds()
            tables, curve_steps = _run_chunk(
                plan, c, cache, devices, _engine_progress(bar, c.rollouts)
            )
            wall = time.perf_counter() - t0
            # compile_s: tracing, lowering and compiling (or loading from the
            # persistent cache) the chunk's programs; run_s: the rest.
            comp = _engine().compile_seconds() - c0
            meta = meta_of(c, curve_steps, wall, compile_s=comp, run_s=wall - comp)
            res.write_chunk(chunks_dir, c.id, tables, meta)
            compile_total += comp
            computed += 1
            bar.end_chunk(c.rollouts)
        _check_interrupt()
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        n_done = sum(1 for c in plan.chunks if res.chunk_done(chunks_dir, c.id))
        close_session()
        if dist.leader:
            _write_manifest(plan, d, "interrupted", session)
        _say(
            f"\ninterrupted: {plan.name} kept {n_done} of {len(plan.chunks)} finished "
            f"chunk(s) in {chunks_dir} ({computed} computed now); the chunk in "
            "flight was dropped. Run the same command again to resume."
        )
        raise
    bar.close()
    close_session()
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
