"""Command line: ``python -m precompute`` (build), ``report``, ``calibrate``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from legs_jax.core.problem import describe_unlearnable, load, unlearnable_poses

from . import catalog, problemset
from ._cli import add_mesh_size_args, add_overwrite_arg, repo_root, tracked_under
from .build import (
    BuildParams,
    build_hash,
    expected_hash,
    is_up_to_date,
    prior_params,
    problem_path,
    problems_dir,
    read_meta,
    reprior,
)
from .calibrate import main as calibrate_main
from .errors import PrecomputeError
from .learned import default_prior
from .mesh import UNITS, check_mesh_kind, source_sha256
from .report import main as report_main
from .runner import Task, run_tasks
from .train_prior import main as train_main

BUILD_HELP = """\
Build problem files from meshes: stable poses and landing probabilities,
topple matrix, T reservoirs of K top-down parallel-jaw grasps per pose, the
ground-truth success probability of every grasp (Embree ray casting under
perturbation) and the prior q: --prior learned (a small GQ-CNN-style network that
sees only the depth image of the pose and the grasp; the default once its weights
are shipped in precompute/prior_weights/) or --prior synthetic (made from p plus
seeded noise; the default while no weights are shipped).

A file current in everything but the prior's constants keeps its poses, grasps
and ground truth; only its prior is recomputed.

The sweep runs on the shipped problem set (data/problemset: the problems the
committed results are made from, the same on every machine) unless told
--problem-source built; builds made here can be compared with it (compare).

Catalogue objects go to <out>/<set>/<name>.npz (default out: the repository's
data/problems). A mesh of your own (--mesh) goes to <out>/custom/<name>.npz with
out defaulting to ./problems under the current folder; the problem file records
where its mesh is (relative to the problem file, and absolutely), so that later
commands find it. Up-to-date files (same mesh, parameters, prior weights and code
version) are skipped; --force rebuilds them.

Meshes of your own: a mesh file (--units needed) or a URDF asset (--units m by
default; its collision mesh, else its visual mesh, at the URDF's scale); --scale
multiplies after that. Pieces that touch or overlap (within 0.5 % of the
bounding-box diagonal) are joined into one rigid body; pieces further apart are
refused. Poses that no method can learn in (no grasp that can succeed, or a pose
a failure never leaves) are warned of, one line each, and recorded in the file.

Other commands:
  python -m precompute report      summary.csv and figures of built problems
                                   (results/precompute for the whole catalogue,
                                   else runs/precompute-report; --out DIR)
  python -m precompute compare     how built problems differ from the shipped set
                                   (data/problemset), array by array
  python -m precompute ship        write the shipped set from built problems
                                   (--overwrite: it replaces committed files)
  python -m precompute calibrate   prior-only gaps per set for a grid of prior noise
  python -m precompute train-prior generate objects, label them, train the learned
                                   prior (--quick: about a minute) into runs/prior
                                   (--out DIR); builds use it when told
                                   --prior-weights runs/prior/weights.npz
"""


def _build_parser() -> argparse.ArgumentParser:
    d = BuildParams()
    p = argparse.ArgumentParser(
        prog="python -m precompute",
        description=BUILD_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--all", action="store_true", help="all 62 catalogue objects")
    what.add_argument(
        "--set",
        dest="set_name",
        metavar="NAME",
        help="one set: dexnet_adv or egad_eval",
    )
    what.add_argument(
        "--object",
        nargs="+",
        action="extend",
        metavar="NAME",
        help="catalogue objects by name",
    )
    what.add_argument(
        "--mesh",
        type=Path,
        metavar="PATH",
        help="your own mesh (.obj/.stl/.ply/.off/.glb/.gltf; needs --units) or a "
        "URDF asset (.urdf: its collision mesh, else its visual mesh, at the "
        "URDF's scale; --units defaults to m). Pieces that touch or overlap are "
        "joined into one rigid body; pieces apart are refused",
    )
    add_mesh_size_args(
        p, "--mesh", " (catalogue meshes know theirs; a URDF defaults to m)"
    )
    p.add_argument(
        "--scale",
        type=float,
        default=1.0,
        metavar="FACTOR",
        help="multiply the mesh by FACTOR after --units (and after a URDF's own "
        "scale), e.g. 0.5 for half size; --mesh only (default 1)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="folder for problem files (default: data/problems for catalogue "
        "objects, or the user cache when data/ is read-only; ./problems under the "
        "current folder for --mesh)",
    )
    p.add_argument("--trials", type=int, default=d.trials, help="reservoirs T (10)")
    p.add_argument(
        "--grasps", type=int, default=d.grasps, help="grasps K per pose (2000)"
    )
    p.add_argument(
        "--samples",
        type=int,
        default=d.samples,
        help=f"perturbation samples per grasp ({d.samples})",
    )
    p.add_argument("--seed", type=int, default=d.seed, help="seed (0)")
    p.add_argument(
        "--prior",
        choices=["learned", "synthetic"],
        default=None,
        help="prior q of the problems (default: learned when its weights are "
        "shipped, else synthetic); files with the other prior go to the "
        "prior-<kind> subfolder of the problems folder",
    )
    p.add_argument(
        "--prior-weights",
        type=Path,
        metavar="PATH",
        help="weights of the learned prior other than the shipped ones (e.g. "
        "runs/prior/weights.npz from train-prior); implies --prior learned. Each "
        "problem file records the weights that made its q (path and SHA-256) and "
        "is rebuilt when they change; catalogue objects built with them go to the "
        "weights-<sha> subfolder of the problems folder",
    )
    p.add_argument(
        "--jobs", type=int, default=None, help="worker processes (default: CPU cores)"
    )
    p.add_argument("--force", action="store_true", help="rebuild up-to-date files too")
    add_overwrite_arg(p, "--out")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _build(argv) -> int:
    import os

    a = _build_parser().parse_args(argv)
    weights = str(a.prior_weights) if a.prior_weights is not None else None
    if weights is not None and a.prior is None:
        a.prior = "learned"
    prior = a.prior if a.prior is not None else default_prior()
    if a.prior is None and prior == "synthetic":
        print(
            "note: no learned-prior weights are shipped yet "
            "(python -m precompute train-prior makes them); using --prior synthetic"
        )
    params = BuildParams(
        trials=a.trials,
        grasps=a.grasps,
        samples=a.samples,
        seed=a.seed,
        prior=prior,
        prior_weights=weights,
    ).check()
    if weights is not None:
        sha = prior_params(params)["weights_sha256"]
        print(f"prior: learned, weights {weights} (sha256 {sha[:12]})")
    if a.jobs is not None and a.jobs < 1:
        raise PrecomputeError(f"--jobs must be at least 1, got {a.jobs}")
    if a.mesh is not None:
        check_mesh_kind(a.mesh)
        if a.units is None and a.mesh.suffix.lower() == ".urdf":
            a.units = "m"  # a URDF's lengths are metres
        if a.units is None:
            raise PrecomputeError(
                f"--mesh {a.mesh} needs --units (one of {', '.join(UNITS)})"
            )
        if not (a.scale > 0 and a.scale < float("inf")):
            raise PrecomputeError(f"--scale must be a positive number, got {a.scale}")
        out = a.out if a.out is not None else Path.cwd() / "problems"
        name = a.mesh.stem
        dest = Path(out) / "custom" / f"{name}.npz"
        _guard_files([dest], out, a.overwrite)
        tasks = [Task(a.mesh, a.units, name, "custom", dest, a.fit, a.scale)]
        skipped = []
        if not a.force and a.mesh.is_file():
            want = build_hash(
                source_sha256(a.mesh), a.units, name, params, a.fit, scale=a.scale
            )
            if is_up_to_date(dest, want):
                tasks, skipped = [], [dest]
    else:
        out = a.out if a.out is not None else problems_dir(prior=prior)
        if a.out is None and weights is not None:
            # apart from the problems of the shipped weights, which they would
            # otherwise replace
            out = out / f"weights-{prior_params(params)['weights_sha256'][:12]}"
        if a.units is not None:
            raise PrecomputeError("--units applies to --mesh only")
        if a.scale != 1.0:
            raise PrecomputeError(
                "--scale applies to --mesh only (catalogue meshes carry their size)"
            )
        if a.fit != "none":
            raise PrecomputeError(
                "--fit applies to --mesh only (catalogue sets carry their own rule)"
            )
        if a.all:
            infos = catalog.objects()
        elif a.set_name:
            infos = catalog.objects(a.set_name)
        else:
            infos = catalog.resolve(a.object)
        from tqdm import tqdm

        tasks, skipped, repriored = [], [], []
        _guard_files([problem_path(i, out) for i in infos], out, a.overwrite)
        # recomputing a learned prior renders and scores every pose: show it
        bar = tqdm(infos, desc="check", unit="obj", disable=a.quiet, leave=False)
        for i in bar:
            bar.set_postfix_str(i.name, refresh=False)
            dest = problem_path(i, out)
            if not a.force and is_up_to_date(dest, expected_hash(i, params)):
                skipped.append(dest)
            elif not a.force and reprior(dest, i, params):
                repriored.append(dest)
            else:
                tasks.append(Task(i.mesh_path, i.units, i.name, i.set, dest, i.fit))
    if skipped:
        print(f"{len(skipped)} up-to-date problem file(s) skipped (--force rebuilds)")
    if a.mesh is None and repriored:
        print(
            f"{len(repriored)} problem file(s) current but for the prior's constants: "
            "prior recomputed, poses and grasps kept"
        )
    if not tasks:
        if a.mesh is not None:
            print(f"problem file: {skipped[0]}")
            _warn_unlearnable([(a.mesh.stem, _recorded_flags(skipped[0]))])
        return 0
    jobs = a.jobs if a.jobs is not None else (os.cpu_count() or 1)
    start = time.perf_counter()
    results = run_tasks(tasks, params=params, jobs=jobs, progress=not a.quiet)
    wall = time.perf_counter() - start
    poses = sum(r[2] for r in results)
    print(
        f"built {len(results)} problem file(s), {poses} poses, in {wall:.1f} s "
        f"-> {Path(out)}"
    )
    if a.mesh is not None:
        print(f"problem file: {tasks[0].dest}")
    _warn_unlearnable([(t.name, r[3]) for t, r in zip(tasks, results, strict=True)])
    return 0


def _guard_files(dests, out: Path, overwrite: bool) -> None:
    """Refuse to write problem files over files committed to the repository (the
    shipped set, say) unless ``overwrite``."""
    if overwrite:
        return
    tracked = {p.resolve() for p in tracked_under(out)}
    hits = [d for d in dests if Path(d).resolve() in tracked]
    if hits:
        shown = Path(hits[0]).resolve().relative_to(repo_root())
        raise PrecomputeError(
            f"--out {out} would replace {len(hits)} file(s) committed to the "
            f"repository (e.g. {shown}): pass --overwrite to replace them, or "
            "choose another --out"
        )


def _recorded_flags(path: Path) -> list:
    """The unlearnable poses a problem file records (worked out from its arrays
    for a file built before they were recorded)."""
    meta = read_meta(path) or {}
    if "unlearnable" in meta:
        return list(meta["unlearnable"] or [])
    try:
        return unlearnable_poses(load(path))
    except Exception:  # noqa: BLE001 - an unreadable file is rebuilt elsewhere
        return []


def _warn_unlearnable(flagged) -> None:
    """One line per pose that cannot be learned (``flagged``: [(name, flags)])."""
    for name, flags in flagged:
        for line in describe_unlearnable(flags):
            print(f"warning: {name}: {line}")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] == "report":
            return report_main(argv[1:])
        if argv and argv[0] == "train-prior":
            return train_main(argv[1:])
        if argv and argv[0] in ("compare", "ship"):
            cmd = (
                problemset.main_compare
                if argv[0] == "compare"
                else problemset.main_ship
            )
            return cmd(argv[1:])
        if argv and argv[0] == "calibrate":
            return calibrate_main(argv[1:])
        return _build(argv)
    except PrecomputeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
