"""Building several problems, in parallel processes, with progress bars, and
``ensure``: the problem files of named objects, built where missing or out of date."""

from __future__ import annotations

import dataclasses
import os
import queue
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from legs_jax.core.problem import save

from . import build as _build
from . import catalog
from .errors import PrecomputeError

__all__ = ["Task", "build_many", "ensure", "run_tasks"]


@dataclasses.dataclass(frozen=True)
class Task:
    """One mesh to build into one problem file."""

    mesh_path: Path
    units: str
    name: str
    set_name: str
    dest: Path
    fit: str = "none"  # size rule (precompute.mesh.FITS)
    scale: float = 1.0  # factor applied after the units (--scale)


def build_many(infos, *, out: Path, params, jobs: int = 1, progress: bool = True):
    """Build the problem files of catalogue objects ``infos`` into ``out``."""
    tasks = [
        Task(i.mesh_path, i.units, i.name, i.set, _build.problem_path(i, out), i.fit)
        for i in infos
    ]
    return run_tasks(tasks, params=params, jobs=jobs, progress=progress)


def ensure(
    names: Sequence[str],
    *,
    data_dir: Path | None = None,
    progress: bool = True,
    jobs: int | None = None,
    params=None,
) -> dict[str, Path]:
    """The problem file of each named object (object or set names), building the
    missing or out-of-date ones. Files live in ``<data>/problems/<set>/<name>.npz``
    (or the user cache when the data folder is read-only; a prior other than the
    default in a subfolder, :func:`precompute.build.problems_dir`); ``params`` a
    :class:`precompute.build.BuildParams` (default: the defaults)."""
    root = Path(data_dir) if data_dir is not None else None
    params = (params or _build.BuildParams()).check()
    out = _build.problems_dir(root, params.prior)
    paths = {
        i.name: _build.problem_path(i, out)
        for i in catalog.resolve(list(names), root=root)
    }
    todo = _build.out_of_date(names, data_dir=root, params=params)
    todo = [
        i for i in todo if not _build.reprior(_build.problem_path(i, out), i, params)
    ]
    if todo:
        build_many(
            todo,
            out=out,
            params=params,
            jobs=jobs if jobs is not None else min(len(todo), os.cpu_count() or 1),
            progress=progress,
        )
    return paths


def _run_one(task: Task, params, messages=None) -> tuple:
    start = time.perf_counter()

    def on_poses(n):
        if messages is not None:
            messages.put(("poses", task.name, n))

    def on_pose_done():
        if messages is not None:
            messages.put(("pose", task.name, 1))

    problem = _build.build_problem(
        task.mesh_path,
        units=task.units,
        fit=task.fit,
        name=task.name,
        set_name=task.set_name,
        params=params,
        scale=task.scale,
        problem_file=task.dest,
        on_poses=on_poses,
        on_pose_done=on_pose_done,
    )
    save(problem, task.dest)
    flags = problem.meta.get("unlearnable", [])
    return task.name, time.perf_counter() - start, problem.num_poses, flags


def _worker_init():
    # one thread per worker for the NumPy/BLAS parts: the processes are the
    # parallelism
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


class _Bars:
    def __init__(self, total_objects: int, enabled: bool):
        self.enabled = enabled
        if not enabled:
            return
        from tqdm import tqdm

        tqdm.monitor_interval = 0
        self.objects = tqdm(total=total_objects, desc="objects", unit="obj", position=0)
        self.poses = tqdm(total=0, desc="poses", unit="pose", position=1)

    def handle(self, msg):
        if not self.enabled:
            return
        kind, name, n = msg
        if kind == "poses":
            self.poses.total += n
            self.poses.refresh()
        elif kind == "pose":
            self.poses.update(n)
            self.poses.set_postfix_str(name, refresh=False)

    def object_done(self, name: str):
        if self.enabled:
            self.objects.update(1)
            self.objects.set_postfix_str(name, refresh=True)

    def close(self):
        if self.enabled:
            self.poses.close()
            self.objects.close()


def run_tasks(tasks: list[Task], *, params, jobs: int = 1, progress: bool = True):
    """Build every task; returns [(name, seconds, poses, unlearnable)] in task
    order (``unlearnable``: :func:`legs_jax.core.problem.unlearnable_poses`).

    A :class:`PrecomputeError` of any task is raised after the other tasks finish
    (their files are kept)."""
    jobs = max(1, min(int(jobs), len(tasks))) if tasks else 1
    bars = _Bars(len(tasks), progress)
    results: dict[str, tuple] = {}
    errors: list[str] = []
    try:
        if jobs == 1:

            class _Direct:
                def put(self, msg):
                    bars.handle(msg)

            direct = _Direct()
            for task in tasks:
                try:
                    results[task.name] = _run_one(task, params, direct)
                except PrecomputeError as e:
                    errors.append(str(e))
                bars.object_done(task.name)
        else:
            _parallel(tasks, params, jobs, bars, results, errors)
    finally:
        bars.close()
    if errors:
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise PrecomputeError(errors[0] + more)
    return [results[t.name] for t in tasks]


def _parallel(tasks, params, jobs, bars, results, errors):
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    if getattr(params, "prior", None) == "learned" or "jax" in sys.modules:
        # the learned prior runs JAX in the workers: a forked copy of a process
        # whose JAX runtime already started can hang, so start them afresh
        method = "spawn"
    ctx = mp.get_context(method)
    with ctx.Manager() as manager:
        messages = manager.Queue()
        with ProcessPoolExecutor(
            max_workers=jobs, mp_context=ctx, initializer=_worker_init
        ) as pool:
            pending = {pool.submit(_run_one, t, params, messages): t for t in tasks}
            while pending:
                done, _ = wait(list(pending), timeout=0.2, return_when=FIRST_COMPLETED)
                _drain(messages, bars)
                for fut in done:
                    task = pending.pop(fut)
                    try:
                        results[task.name] = fut.result()
                    except PrecomputeError as e:
                        errors.append(str(e))
                    bars.object_done(task.name)
            _drain(messages, bars)


def _drain(messages, bars):
    while True:
        try:
            bars.handle(messages.get_nowait())
        except queue.Empty:
            return
