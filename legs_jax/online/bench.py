"""``python -m legs_jax.online bench``: the timing targets of the online session.

- ask + tell for a known pose (median over ``repeats`` pairs; tell includes the
  fsync of the log record), LEGS and BORGES (K=2000);
- recognition of a 640×480 image once every pose of the object is cached (the
  deprojection, segmentation, voxel grid, yaw search over every cached pose and
  ICP; median over views);
- recognition of a new pose (the view of a pose not yet cached, against the
  poses cached before it);
- a new pose's reservoir of 2000 grasps (antipodal sampling on the image and the
  session's default prior, the learned one; median over views);
- the first requests of a restarted ``serve`` (a fresh process, JAX's persistent
  compilation cache warm from an earlier process): observe, ask, tell, bound,
  each timed from the request to its reply.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from legs_jax.core import methods
from legs_jax.online import recognition as R
from legs_jax.online import sampler as S
from legs_jax.online.camera import check_depth
from legs_jax.online.robot import SimRobot, World
from legs_jax.online.session import Session

__all__ = ["main", "time_ask_tell", "time_first_requests"]


def time_ask_tell(method: str, depth, intr: dict, repeats: int) -> tuple:
    """(median wall, 90th percentile wall, median CPU) seconds of one ask + tell
    in a known pose."""
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        with Session.create(tmp + "/s", method) as ses:
            ses.observe(depth, intr)
            for _ in range(5):  # compile
                ses.ask()
                ses.tell(bool(rng.random() < 0.5))
            out, cpu = [], []
            for _ in range(repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                ses.ask()
                ses.tell(bool(rng.random() < 0.5))
                out.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
    return float(np.median(out)), float(np.quantile(out, 0.9)), float(np.median(cpu))


def _reply(proc: subprocess.Popen, what: str) -> dict:
    """The next reply line of a ``serve`` process; a clear error where it ended."""
    line = proc.stdout.readline()
    if not line:
        raise RuntimeError(
            f"serve ended before it answered {what} (exit code {proc.wait()})"
        )
    reply = json.loads(line)
    if not reply.get("ok"):
        raise RuntimeError(f"{what} refused: {reply}")
    return reply


def _exchange(proc: subprocess.Popen, reqs: list[dict]) -> dict:
    """Seconds to open the session and to answer each request, in order."""
    times = {}
    t0 = time.perf_counter()
    _reply(proc, "the start")
    times["open"] = time.perf_counter() - t0
    for i, req in enumerate(reqs, 1):
        t0 = time.perf_counter()
        proc.stdin.write(json.dumps({"id": i, **req}) + "\n")
        proc.stdin.flush()
        _reply(proc, req["cmd"])
        times[req["cmd"]] = time.perf_counter() - t0
    proc.stdin.write('{"cmd": "quit"}\n')
    proc.stdin.close()
    proc.wait(timeout=60)
    return times


def time_first_requests(method: str, depth, intr: dict, cache: str) -> dict:
    """Wall seconds from request to reply of the first observe, ask, tell and
    bound of a ``serve`` process on a new session, in a process started after
    another one ran the same requests with the same compilation cache."""
    reqs = [
        {"cmd": "observe", "depth": None, "intrinsics": intr},
        {"cmd": "ask"},
        {"cmd": "tell", "success": True},
        {"cmd": "bound", "rho_min": 0.9},
    ]
    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp) / "view.npy", np.asarray(depth, np.float32))
        reqs[0]["depth"] = {"npy": str(Path(tmp) / "view.npy")}
        for run in ("warm-up", "timed"):
            with subprocess.Popen(
                [sys.executable, "-m", "legs_jax.online", "serve", f"{tmp}/{run}"]
                + ["--method", method, "--compile-cache", cache],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                env={**os.environ, "PYTHONWARNINGS": "ignore"},
            ) as proc:
                try:
                    times = _exchange(proc, reqs)
                finally:  # a serve that died or hangs is not left behind
                    if proc.poll() is None:
                        proc.kill()
    return times


def _timed_methods() -> tuple[str, str]:
    """The default method and the first dense method of the benchmark's table:
    an active set of k slots against all K grasps."""
    dense = [
        m
        for m in methods.names()
        if methods.get(m).card.bench and methods.get(m).card.dense
    ]
    return methods.DEFAULT, dense[0]


def main(args) -> int:
    world = World.from_mesh(args.object)
    robot = SimRobot(world, np.random.default_rng(1))
    intr = robot.intrinsics
    views = []
    for s in range(world.num_poses):
        robot.place(s)
        views.append(check_depth(robot.render(), intr))
    print(f"machine: {platform.processor() or platform.machine()}, {args.object}")
    methods_timed = _timed_methods()
    for method in methods_timed:
        med, p90, cpu = time_ask_tell(method, views[0], intr.to_dict(), args.repeats)
        print(
            f"ask+tell {method}: median {1000 * med:.1f} ms, 90th percentile "
            f"{1000 * p90:.1f} ms (CPU {1000 * cpu:.1f} ms)"
        )
    with tempfile.TemporaryDirectory() as cache:
        first = time_first_requests(methods_timed[0], views[0], intr.to_dict(), cache)
    print(
        f"first requests of a restarted serve ({methods_timed[0]}, warm compilation "
        "cache): " + ", ".join(f"{k} {v:.2f} s" for k, v in first.items())
    )
    prior = S.default_prior(S.DEFAULT_PRIOR)
    lib = R.PoseLibrary()
    res, new = [], []
    for d in views:
        t0, c0 = time.perf_counter(), time.process_time()
        pts, _ = R.object_cloud(d, intr, robot.camera_pose)
        _, cloud = lib.recognise(pts)
        if len(lib):  # the first pose meets an empty library: nothing to search
            new.append((time.perf_counter() - t0, time.process_time() - c0))
        lib.add(cloud)
        t0, c0 = time.perf_counter(), time.process_time()
        view = S.View(d, intr, robot.camera_pose)
        g = S.sample_grasps(d, intr, robot.camera_pose, 2000, np.random.default_rng(0))
        prior(g, view)
        res.append((time.perf_counter() - t0, time.process_time() - c0))
    rec = []
    for _ in range(3):
        for s in range(world.num_poses):
            robot.place(s)
            d = check_depth(robot.render(), intr)
            t0, c0 = time.perf_counter(), time.process_time()
            pts, _ = R.object_cloud(d, intr, robot.camera_pose)
            lib.recognise(pts)
            rec.append((time.perf_counter() - t0, time.process_time() - c0))
    rec, res, new = np.asarray(rec), np.asarray(res), np.asarray(new)
    print(
        f"recognition of a {intr.width}x{intr.height} image with {len(lib)} cached "
        f"poses: median {np.median(rec[:, 0]):.3f} s, max {rec[:, 0].max():.3f} s "
        f"(CPU median {np.median(rec[:, 1]):.3f} s)"
    )
    if len(new):
        print(
            f"recognition of a new pose (against the poses cached before it): "
            f"median {np.median(new[:, 0]):.3f} s, max {new[:, 0].max():.3f} s "
            f"(CPU median {np.median(new[:, 1]):.3f} s)"
        )
    print(
        f"new pose reservoir of 2000 grasps with the {S.prior_name(prior)} prior: "
        f"median {np.median(res[:, 0]):.3f} s, max {res[:, 0].max():.3f} s "
        f"(CPU median {np.median(res[:, 1]):.3f} s)"
    )
    return 0
