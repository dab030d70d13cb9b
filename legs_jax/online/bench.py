"""``python -m legs_jax.online bench``: the timing targets of the online session.

- ask + tell for a known pose (median over ``repeats`` pairs; tell includes the
  fsync of the log record), LEGS and BORGES (K=2000);
- recognition of a 640×480 image once every pose of the object is cached (the
  deprojection, segmentation, voxel grid, yaw search over every cached pose and
  ICP; median over views);
- a new pose's reservoir of 2000 grasps (antipodal sampling on the image and the
  stand-in prior; median over views).
"""

from __future__ import annotations

import platform
import tempfile
import time

import numpy as np

from legs_jax.online import recognition as R
from legs_jax.online import sampler as S
from legs_jax.online.camera import check_depth
from legs_jax.online.robot import SimRobot, World
from legs_jax.online.session import Session

__all__ = ["main", "time_ask_tell"]


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


def _timed_methods() -> tuple[str, str]:
    """The default method and the first dense method of the benchmark's table:
    an active set of k slots against all K grasps."""
    from legs_jax.core import methods

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
    for method in _timed_methods():
        med, p90, cpu = time_ask_tell(method, views[0], intr.to_dict(), args.repeats)
        print(
            f"ask+tell {method}: median {1000 * med:.1f} ms, 90th percentile "
            f"{1000 * p90:.1f} ms (CPU {1000 * cpu:.1f} ms)"
        )
    lib = R.PoseLibrary()
    res = []
    for d in views:
        pts, _ = R.object_cloud(d, intr, robot.camera_pose)
        _, cloud = lib.recognise(pts)
        lib.add(cloud)
        t0, c0 = time.perf_counter(), time.process_time()
        S.geometric_prior(
            S.sample_grasps(d, intr, robot.camera_pose, 2000, np.random.default_rng(0))
        )
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
    rec, res = np.asarray(rec), np.asarray(res)
    print(
        f"recognition of a {intr.width}x{intr.height} image with {len(lib)} cached "
        f"poses: median {np.median(rec[:, 0]):.3f} s, max {rec[:, 0].max():.3f} s "
        f"(CPU median {np.median(rec[:, 1]):.3f} s)"
    )
    print(
        f"new pose reservoir of 2000 grasps: median {np.median(res[:, 0]):.3f} s, "
        f"max {res[:, 0].max():.3f} s (CPU median {np.median(res[:, 1]):.3f} s)"
    )
    return 0
