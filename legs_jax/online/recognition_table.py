"""Pose recognition on simulated views: the right-pose and duplicate fractions.

For each object: its stable poses from the mesh (:meth:`World.from_mesh`, the
model of precompute/; no grasps are needed), then ``views`` simulated depth
images (640×480, σ = 1 mm noise, 0.5 % missing pixels; each at a random place
and yaw). The first P views show every pose once (in a random order), the rest
are drawn from the landing probabilities λ. Each view goes through the
session's recognition (:class:`PoseLibrary`), caching a new pose when nothing
matches. A view counts as right when it is assigned the cached pose whose first
view showed the same true pose, or when it creates a new pose for a true pose
not cached before. Duplicates: new poses whose true pose was already cached,
over all new poses.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from legs_jax.online import recognition as R
from legs_jax.online.camera import check_depth
from legs_jax.online.errors import InputError
from legs_jax.online.outputs import is_results, out_file, refuse_tracked
from legs_jax.online.robot import SimRobot, World

__all__ = ["DEXNET_OBJECTS", "SHIPPED", "evaluate_object", "main"]

DEXNET_OBJECTS = (
    "bar_clamp",
    "climbing_hold",
    "endstop_holder",
    "gearbox",
    "mount1",
    "mount2",
    "nozzle",
    "part1",
    "part3",
    "pawn",
    "pipe_connector",
    "turbine_housing",
    "vase",
)

# The configuration of the shipped table, results/online/recognition.md (its
# "Regenerate" line): the command line's defaults.
SHIPPED = {"objects": DEXNET_OBJECTS, "views": 40, "seed": 0}


def evaluate_object(world: World, views: int, seed: int, on_view=None) -> dict:
    """Recognise ``views`` simulated views of ``world``; counts and timings."""
    rng = np.random.default_rng([seed, 7])
    robot = SimRobot(world, rng)
    lib = R.PoseLibrary(seed=seed)
    label: list[int] = []  # true pose of each cached pose
    P = world.num_poses
    order = list(rng.permutation(P)) + [None] * max(0, views - P)
    right = new = dup = wrong_merge = 0
    seconds = []
    for v in range(views):
        robot.place(order[v] if v < len(order) else None)
        depth = check_depth(robot.render(), robot.intrinsics)
        t0 = time.perf_counter()
        pts, _ = R.object_cloud(depth, robot.intrinsics, robot.camera_pose)
        match, cloud = lib.recognise(pts)
        seconds.append(time.perf_counter() - t0)
        truth = robot.pose
        if match.pose is None:
            new += 1
            if truth in label:
                dup += 1
            else:
                right += 1
            lib.add(cloud)
            label.append(truth)
        elif label[match.pose] == truth:
            right += 1
        else:
            wrong_merge += 1
        if on_view is not None:
            on_view()
    return {
        "object": world.name,
        "poses": P,
        "views": views,
        "right": right,
        "new": new,
        "duplicates": dup,
        "wrong_merges": wrong_merge,
        "cached": len(lib),
        "median_s": float(np.median(seconds)),
    }


def table_markdown(
    rows: list[dict], views: int, seed: int, objects: list[str] | None = None
) -> str:
    """The markdown table; ``objects``: the names asked for (default: the 13
    Dex-Net objects), written into its "Regenerate" command."""
    names = list(objects) if objects else list(DEXNET_OBJECTS)
    chosen = "" if names == list(DEXNET_OBJECTS) else " --objects " + " ".join(names)
    lines = [
        "# Pose recognition on simulated views",
        "",
        "Regenerate: `python -m legs_jax.online recognition-table "
        f"--views {views} --seed {seed}{chosen}`.",
        "",
        "Per object: its stable poses from the mesh (the model of `precompute/`), "
        f"{views} simulated overhead depth images (640×480, fx = fy = 525 px, camera "
        "0.7 m above the table, depth noise σ = 1 mm, 0.5 % missing pixels), each "
        "with the object at a random place (±5 cm) and yaw; the first P views "
        "show every pose once, the rest are drawn from the landing probabilities. "
        f"Recognition as in the session: 2 mm voxels, tolerance "
        f"{R.TOLERANCE * 1000:g} mm, match when ≥ {R.MATCH_FRACTION:.0%} of the "
        "points lie within it both ways after the yaw search and ICP.",
        "",
        "- right: views given the right pose (a new pose for a true pose not seen "
        "before counts as right);",
        "- duplicates: new poses created for a true pose already cached, over all "
        "new poses;",
        "- wrong merges: views assigned to a cached pose of another true pose;",
        "- median recognition: wall seconds per view (deprojection to match) on the "
        "machine that ran the table, with whatever else it was running.",
        "",
        "| object | poses | views | right | new poses | duplicates | wrong merges "
        "| median recognition (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['object']} | {r['poses']} | {r['views']} | "
            f"{r['right'] / r['views']:.1%} | {r['new']} | "
            f"{r['duplicates'] / max(r['new'], 1):.1%} | {r['wrong_merges']} | "
            f"{r['median_s']:.2f} |"
        )
    tv = sum(r["views"] for r in rows)
    tr = sum(r["right"] for r in rows)
    tn = sum(r["new"] for r in rows)
    td = sum(r["duplicates"] for r in rows)
    tw = sum(r["wrong_merges"] for r in rows)
    lines.append(
        f"| **all** | {sum(r['poses'] for r in rows)} | {tv} | **{tr / tv:.1%}** | "
        f"{tn} | **{td / max(tn, 1):.1%}** | {tw} | "
        f"{np.median([r['median_s'] for r in rows]):.2f} |"
    )
    lines.append("")
    lines.append("Targets: ≥ 95 % right, ≤ 2 % duplicates.")
    return "\n".join(lines) + "\n"


def main(args) -> int:
    from tqdm.auto import tqdm

    names = args.objects or list(DEXNET_OBJECTS)
    if args.views < 1:
        raise InputError(f"--views must be at least 1, got {args.views}")
    shipped = is_shipped(names, args.views, args.seed)
    out = out_file(args.out, "recognition.md", shipped)
    refuse_tracked([out], args.overwrite or (shipped and is_results(out)))
    rows = []
    bar = None if args.quiet else tqdm(total=len(names) * args.views, unit="view")
    for name in names:
        try:
            world = World.from_mesh(name)
        except ValueError as e:  # PrecomputeError: unknown object, bad mesh
            raise InputError(str(e)) from None
        if bar is not None:
            bar.set_description(name)
        rows.append(
            evaluate_object(
                world, args.views, args.seed, None if bar is None else bar.update
            )
        )
    if bar is not None:
        bar.close()
    text = table_markdown(rows, args.views, args.seed, names)
    notes = kept_notes(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text + notes)
    print(text)
    if notes:
        print(
            f"kept the notes below the table in {out}; check that they still "
            "describe the new numbers"
        )
    print(f"wrote {out}")
    if args.out is None and not shipped:
        print(
            "(not results/online/recognition.md: the shipped table is the 13 "
            f"objects, {SHIPPED['views']} views, seed {SHIPPED['seed']}; --out "
            "names another place)"
        )
    return 0


def kept_notes(path: Path) -> str:
    """The notes written below the table of an existing file (everything after
    its "Targets:" line), which regenerating the table keeps; "" when there are
    none."""
    if not path.is_file():
        return ""
    old = path.read_text()
    at = old.find("\nTargets:")
    end = old.find("\n", at + 1) if at >= 0 else -1
    return old[end + 1 :] if end >= 0 else ""


def is_shipped(names, views: int, seed: int) -> bool:
    """Whether this is the configuration of the shipped table (:data:`SHIPPED`)."""
    return (
        list(names) == list(SHIPPED["objects"])
        and views == SHIPPED["views"]
        and seed == SHIPPED["seed"]
    )
