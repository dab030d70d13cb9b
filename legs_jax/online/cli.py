"""``python -m legs_jax.online``: serve a session, simulate one, measure recognition."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import precompute
from legs_jax._cli import compile_cache_arg, quiet_arg
from legs_jax._jax_cache import compile_cache
from legs_jax.core import methods
from legs_jax.core import problem as problem_mod
from legs_jax.errors import ConfigError
from legs_jax.online._adapter import default_method, method_names
from legs_jax.online.agreement import main as agreement_main
from legs_jax.online.bench import main as bench_main
from legs_jax.online.camera import default_camera_pose
from legs_jax.online.errors import InputError, OrderError, StateError
from legs_jax.online.outputs import refuse_tracked
from legs_jax.online.protocol import refuse, serve
from legs_jax.online.recognition_table import SHIPPED as SHIPPED_TABLE
from legs_jax.online.recognition_table import main as table_main
from legs_jax.online.robot import World
from legs_jax.online.sampler import DEFAULT_PRIOR, PRIORS
from legs_jax.online.session import NO_SUCCESS_ATTEMPTS, ONE_POSE_STEPS, Session
from legs_jax.online.simulate import EVAL_SAMPLES, Simulation
from precompute import problemset
from precompute._cli import add_mesh_size_args
from precompute.errors import PrecomputeError
from precompute.mesh import _MESH_SUFFIXES

_DESCRIPTION = """\
LEGS on a robot: an online exploration session over depth images.

Commands:
  serve DIR       drive a session from a robot program: JSON requests on stdin,
                  one JSON response per line on stdout (see the README, "On a
                  robot"). Creates the session in DIR, or resumes the one there
                  with every recorded outcome.
  simulate        run a session against the simulated robot (depth rendering
                  and grasp physics of precompute/), write it to --out with a
                  learning-curve figure; --resume continues a killed run.
  recognition-table
                  pose recognition on simulated views of objects: the fraction
                  of views assigned the right pose and of duplicate new poses.
  agreement       the simulated loop against the batched engine on a problem.
  bench           time ask+tell, recognition of a 640x480 image, a new
                  pose's reservoir and the first requests of a restarted serve.

recognition-table and agreement write the shipped tables in results/online/
only when run at the configuration that produced them; any other run writes to
runs/online/ (or --out) and says where. A file tracked by git (a shipped
result) is otherwise never replaced, and serve and simulate refuse a folder
holding one, unless given --overwrite.

Run "python -m legs_jax.online COMMAND --help" for a command's options.
"""


def _session_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--method",
        default=default_method(),
        help=f"exploration method: {', '.join(method_names())} (default "
        f"{default_method()})",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the method's draws (0)")
    p.add_argument(
        "--max-poses", type=int, default=24, help="pose capacity of the session (24)"
    )
    p.add_argument(
        "--reservoir",
        type=int,
        default=2000,
        help="grasps sampled for each new pose (2000)",
    )
    p.add_argument(
        "--prior",
        choices=tuple(PRIORS),
        default=None,
        help="what scores a new pose's grasps: learned (default; the network that "
        "scores the problem files, on the session's depth image) or geometric (a "
        "stand-in from the edge normals alone); kept by a resumed session",
    )
    p.add_argument(
        "--hparam",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="one of the method's own hyperparameters (those its declaration "
        "lists, e.g. LEGS: s, prior_offset, delta, gamma, k, n), repeatable",
    )
    p.add_argument(
        "--bound-replicates",
        type=int,
        default=0,
        metavar="R",
        help="our stopping bound's fit of each pose's grasp distribution: 0 "
        "(default) one plug-in fit; R > 0 averaged over R bootstrap refits, more "
        "often valid on hard objects, about four times the cost of a check (8 or "
        "16 are reasonable); kept by a resumed session",
    )


def _cache_arg(p: argparse.ArgumentParser) -> None:
    compile_cache_arg(p, "a restarted session skips compiling")


def _overwrite_arg(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--overwrite", action="store_true", help=what)


_FOLDER_OVERWRITE = (
    "write the {} into a folder that holds files tracked by git (shipped results, "
    "e.g. under results/online), replacing those of the same name; without it "
    "such a folder is refused"
)
_TABLE_OVERWRITE = (
    "replace a file tracked by git (a shipped result under results/online) "
    "although this is not the configuration that produced it; without it that is "
    "refused"
)


def _hparams(items, method: str) -> dict:
    """``--hparam`` values by name: integers for those ``method`` declares
    integer, floats for the others (the method checks names and ranges)."""
    out = {}
    integer: set[str] = set()
    if items:
        ranges = methods.resolve(method).ranges
        integer = {name for name, rng in ranges.items() if rng.integer}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise InputError(f"--hparam takes NAME=VALUE, got {item!r}")
        try:
            v = float(value)
        except ValueError:
            raise InputError(f"--hparam {name}: {value!r} is not a number") from None
        out[name] = int(v) if name in integer and v.is_integer() else v
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m legs_jax.online",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser(
        "serve",
        help="drive a session with JSON lines on stdin/stdout",
        description="Serve the session in DIR over stdin/stdout, one JSON object "
        "per line (requests: observe, ask, tell, bound, status, quit). The "
        "session is created when DIR holds none (with the options below) and "
        "resumed otherwise. Every outcome is on disk before its response is "
        "written. Warnings go to stderr, one line each, once: a pose with no "
        f"success in {NO_SUCCESS_ATTEMPTS} grasp attempts, and recognition that "
        f"has seen one pose only after {ONE_POSE_STEPS} steps.",
    )
    p.add_argument("dir", type=Path, help="session folder")
    _session_args(p)
    p.add_argument(
        "--camera-height",
        type=float,
        default=0.7,
        help="a camera straight above the table origin at this height (m); "
        "use --camera-pose for any other mounting (0.7)",
    )
    p.add_argument(
        "--camera-pose",
        type=Path,
        help="a .npy 4x4 camera -> table transform (table plane z = 0, z up)",
    )
    _overwrite_arg(p, _FOLDER_OVERWRITE.format("session"))
    _cache_arg(p)

    p = sub.add_parser(
        "simulate",
        help="run a session against the simulated robot",
        description="Run a session against the simulated robot: noisy depth images "
        "of the object in a stable pose at a random place and yaw, grasps executed "
        "with the perturbed physics of precompute/, drops and topples with the "
        "object's landing and topple probabilities. Writes the session, "
        "curve.jsonl and learning_curve.png to --out. Warnings go to stderr: "
        "before the run, the poses of the problem file where no grasp can "
        "succeed; "
        f"during it, once each, a pose with no success in {NO_SUCCESS_ATTEMPTS} "
        "grasp attempts and recognition that has seen one pose only after "
        f"{ONE_POSE_STEPS} steps; after it, a run without any success.",
    )
    p.add_argument(
        "--object",
        help="catalogue object (e.g. bar_clamp), a problem file (.npz, e.g. made "
        "by python -m precompute --mesh) or a mesh file (.obj/.stl/.ply/.off, with "
        "--units; poses computed from the mesh)",
    )
    add_mesh_size_args(p, "a mesh file given as --object (as precompute --mesh)")
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="grasp attempts (1000; with --resume, the run's own unless given)",
    )
    p.add_argument("--out", type=Path, required=True, help="session folder")
    p.add_argument(
        "--resume", action="store_true", help="continue the (killed) run in --out"
    )
    _overwrite_arg(p, _FOLDER_OVERWRITE.format("run"))
    p.add_argument(
        "--problem",
        type=Path,
        help="problem file of the object (.npz): its poses, and the best grasps "
        "for the gap curve (default: the built one if there is one, else poses "
        "from the mesh and no gap)",
    )
    p.add_argument(
        "--given-poses",
        action="store_true",
        help="tell the session the true pose and use the problem file's "
        "reservoirs (no recognition): the batched engine's loop",
    )
    p.add_argument("--trial", type=int, default=0, help="problem trial (0)")
    p.add_argument(
        "--eval-every",
        type=int,
        default=None,
        help="curve point every N steps (default: steps / 50, at most 100; with "
        "--resume, the run's own unless given)",
    )
    p.add_argument(
        "--stop-at",
        type=float,
        metavar="RHO_MIN",
        help="stop at the first curve point whose stopping bound (ours, "
        "legs_jax.core.stopping) is at least RHO_MIN",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="with --stop-at: where the bound reaches RHO_MIN, try the frozen "
        "recommended grasps until a sequential test certifies RHO_MIN (stop) or "
        "refutes it (explore on); a run stops below RHO_MIN with probability at "
        "most 0.05 (legs_jax.core.verify)",
    )
    quiet_arg(p)
    _session_args(p)
    _cache_arg(p)

    p = sub.add_parser(
        "recognition-table",
        help="pose recognition on simulated views",
        description="Recognise the stable poses of simulated views (random place, "
        "yaw and sensor noise) of each object, with poses computed from the mesh; "
        "write a markdown table of the fraction of views given the right pose and "
        "the fraction of new poses that duplicate a known one.",
    )
    p.add_argument(
        "--objects",
        nargs="+",
        action="extend",
        default=None,
        help="catalogue objects (default: the 13 Dex-Net objects)",
    )
    p.add_argument(
        "--views",
        type=int,
        default=SHIPPED_TABLE["views"],
        help=f"views per object ({SHIPPED_TABLE['views']})",
    )
    p.add_argument("--seed", type=int, default=SHIPPED_TABLE["seed"], help="seed (0)")
    p.add_argument(
        "--out",
        type=Path,
        help="the markdown table: a .md file, or a folder to write recognition.md "
        "in (default: results/online/recognition.md, the shipped table, at the "
        "configuration that produced it, the defaults; runs/online/recognition.md "
        "at any other)",
    )
    _overwrite_arg(p, _TABLE_OVERWRITE)
    quiet_arg(p)

    p = sub.add_parser(
        "agreement",
        help="the simulated online loop against the batched engine",
        description="Run sessions against the simulated robot with the true pose "
        "given and a problem file's reservoirs, and the batched engine on the same "
        "problem; write a markdown table of the mean gap curves and whether they "
        "agree (3 standard errors + 0.02 at every step, KS test of the final "
        "gaps), and a figure. Optionally also sessions with recognition.",
    )
    p.add_argument("--problem", type=Path, required=True, help="problem file (.npz)")

    p.add_argument(
        "--method", default=default_method(), help=f"method ({default_method()})"
    )
    p.add_argument("--rollouts", type=int, default=30, help="online sessions (30)")
    p.add_argument(
        "--engine-rollouts", type=int, default=500, help="engine rollouts (500)"
    )
    p.add_argument("--horizon", type=int, default=500, help="steps (500)")
    p.add_argument("--every", type=int, default=50, help="curve step (50)")
    p.add_argument(
        "--recognition-rollouts",
        type=int,
        default=0,
        help="sessions with recognition and observed reservoirs (0)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="the markdown table: a .md file, or a folder to write agreement.md in; "
        "the figure goes next to it (.png) (default: results/online/agreement.md, "
        "the shipped table, at the configuration that produced it, its Regenerate "
        "line; runs/online/agreement.md at any other)",
    )
    _overwrite_arg(p, _TABLE_OVERWRITE)
    quiet_arg(p)
    _cache_arg(p)

    p = sub.add_parser(
        "bench",
        help="time the targets",
        description="Medians of ask+tell for a known pose, recognition of a "
        "640x480 image of a known and of a new pose, and a new pose's reservoir of "
        "2000 grasps scored by the learned prior, on the simulated camera; and the "
        "first observe, ask, tell and bound of a restarted serve process with a "
        "warm compilation cache (a throw-away cache of its own).",
    )
    p.add_argument("--object", default="bar_clamp", help="catalogue object")
    p.add_argument("--repeats", type=int, default=200, help="ask+tell pairs (200)")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        if args.command == "serve":
            compile_cache(args.compile_cache)
            return _serve(args)
        if args.command == "simulate":
            return _simulate(args)  # turns the cache on once its arguments pass
        if args.command == "recognition-table":
            return table_main(args)
        if args.command == "agreement":
            compile_cache(args.compile_cache)
            return agreement_main(args)
        if args.command == "bench":
            return bench_main(args)
    except (InputError, OrderError, StateError, ConfigError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0


def _serve(args) -> int:
    import numpy as np

    try:
        refuse_tracked([args.dir], args.overwrite)
        if (args.dir / "session.json").exists():
            session = Session.open(args.dir)
            _same_prior(session, args.prior)
        else:
            if args.camera_pose is not None:
                try:
                    cam = np.load(args.camera_pose, allow_pickle=False)
                except (OSError, ValueError) as e:
                    raise InputError(f"cannot read --camera-pose: {e}") from None
            else:
                cam = default_camera_pose(args.camera_height)
            session = Session.create(
                args.dir,
                args.method,
                hparams=_hparams(args.hparam, args.method),
                seed=args.seed,
                max_poses=args.max_poses,
                reservoir_size=args.reservoir,
                camera_pose=cam,
                prior=args.prior or DEFAULT_PRIOR,
                bound_replicates=args.bound_replicates,
            )
    except (InputError, OrderError, StateError, ConfigError) as e:
        return refuse(e)  # the robot program reads JSON lines, errors too
    with session:
        return serve(session)


def _find_problem(name: str):
    """The problem file of catalogue object ``name``: built on this machine
    (``python -m precompute``) when there is one, else the shipped one, else None."""
    info = precompute.catalog.lookup(name)
    path = precompute.build.problem_path(info, precompute.build.problems_dir())
    if path.is_file():
        return path
    try:
        return problemset.paths([name])[name]
    except PrecomputeError:
        return None


def _rate(sim) -> str:
    """What the curve's ``performance`` is: exact with the true poses given, else
    estimated from the perturbed executions of each pose's recommended grasp."""
    if sim.given:
        return "true success rate of the recommendations"
    return (
        f"success rate of the recommendations (estimated from {EVAL_SAMPLES} "
        "executions a pose)"
    )


def _print_stop(sim, stop_at, verify: bool = False) -> None:
    if stop_at is None:
        return
    r = sim.stopped
    v = sim.session.verification_state()
    if verify and r is not None:
        st = v["stopped"]
        print(
            f"stopped at step {r['step']}: rho_min {stop_at:.3f} certified by "
            f"{st['attempts']} attempts of the frozen recommendations after a "
            f"landing ({st['successes']} successes; {st['phase_steps']} steps in "
            f"verification phase {st['phase']}); {_rate(sim)} "
            f"{r['performance']:.3f}"
        )
        return
    if r is None:
        if verify and v is not None:
            print(
                f"no stop: {v['phase']} verification phase(s) at rho_min = "
                f"{stop_at:.3f}, none certified"
            )
        else:
            print(f"no stop: our bound stayed below rho_min = {stop_at:.3f}")
        return
    print(
        f"stopped at step {r['step']}: our bound {r['p_lower_ours']:.3f} >= rho_min "
        f"{stop_at:.3f}; {_rate(sim)} "
        f"{r['performance']:.3f} (the paper's bound {r['p_lower']:.3f})"
    )


def _same_prior(session, prior: str | None) -> None:
    """A resumed session keeps its prior: refuse another one named anew."""
    had = session.store.config.get("prior", DEFAULT_PRIOR)
    if prior is not None and prior != had:
        session.close()
        raise InputError(
            f"the session in {session.store.folder} scores new poses with the "
            f"{had} prior; --prior {prior} cannot change it (leave --prior out)"
        )


def _simulate(args) -> int:
    if args.steps is not None and args.steps < 1:
        raise InputError(f"--steps must be at least 1, got {args.steps}")
    if args.eval_every is not None and args.eval_every < 1:
        raise InputError(f"--eval-every must be at least 1, got {args.eval_every}")
    if args.verify and args.stop_at is None:
        raise InputError("--verify needs --stop-at RHO_MIN, the threshold to test")
    if args.verify and not 0.0 < args.stop_at < 1.0:
        raise InputError(f"--stop-at must be in (0, 1) to verify, got {args.stop_at}")
    if args.object is None and args.problem is None:
        raise InputError(
            "name the object: --object NAME|PROBLEM.npz|MESH, or --problem"
        )
    refuse_tracked([args.out], args.overwrite)
    if not args.resume and (args.out / "session.json").exists():
        raise StateError(
            f"{args.out} already holds a session: add --resume to continue it, or "
            "choose another --out"
        )
    name, mesh, path = args.object, None, args.problem
    if name is not None and Path(name).suffix.lower() == ".npz":
        if path is not None:
            raise InputError("a problem file twice: as --object and as --problem")
        name, path = None, Path(name)
    elif name is not None and Path(name).suffix.lower() in _MESH_SUFFIXES:
        mesh, name = Path(name), Path(name).stem
        if not mesh.is_file():
            raise InputError(f"no such mesh file: {mesh}")
    try:
        if path is None and mesh is None:
            path = _find_problem(name)
        pb = None
        if path is not None:
            try:
                pb = problem_mod.load(path)
            except (OSError, ValueError) as e:
                raise InputError(f"cannot read problem file {path}: {e}") from None
            if name is not None and mesh is None and pb.name != name:
                raise InputError(f"{path} is the problem of {pb.name}, not {name}")
            g = pb.meta.get(
                "geometry_trials", None if pb.meta.get("geometry", True) else 0
            )
            if args.given_poses and g is not None and args.trial >= g:
                held = f"trials 0-{g - 1}" if g > 1 else "trial 0" if g else "no trial"
                raise InputError(
                    f"--given-poses needs the grasps of trial {args.trial}, but the "
                    f"problem file {path} holds the grasp geometry of {held} only "
                    f"(the shipped set keeps it for the objects that figures draw): "
                    f"build the file with python -m precompute --objects {pb.name}"
                    + (", or choose --trial 0" if g else "")
                )
            world = World.from_problem(pb, mesh_path=mesh, problem_path=path)
        else:
            if args.given_poses:
                raise InputError(
                    f"--given-poses needs the problem file of {name}: build it "
                    f"with python -m precompute, or pass --problem"
                )
            if mesh is not None:
                if args.units is None:
                    raise InputError(f"the mesh {mesh} needs --units (m, cm or mm)")
                world = World.from_mesh_file(mesh, args.units, args.fit)
            else:
                world = World.from_mesh(name)
    except PrecomputeError as e:
        raise InputError(str(e)) from None
    compile_cache(args.compile_cache)  # not before: a refused command turns nothing on
    if pb is not None:
        # the poses where no grasp can succeed (in some trial); a pose that a
        # failure never leaves but a success can is learnable, and common (every
        # pose of the shipped bar_clamp): no warning for that alone
        flags = problem_mod.unlearnable_poses(pb)
        dead = [f for f in flags if f["trials_without_success"]]
        for line in problem_mod.describe_unlearnable(dead):
            print(f"warning: the problem of {pb.name}: {line}", file=sys.stderr)
    sim = Simulation(
        args.out,
        world,
        method=args.method,
        seed=args.seed,
        resume=args.resume,
        problem=pb,
        trial=args.trial,
        given_poses=args.given_poses,
        hparams=_hparams(args.hparam, args.method),
        max_poses=args.max_poses,
        reservoir_size=args.reservoir,
        eval_every=args.eval_every,
        steps=args.steps,
        prior=args.prior or DEFAULT_PRIOR,
        bound_replicates=args.bound_replicates,
    )
    if args.resume:
        _same_prior(sim.session, args.prior)
    try:
        sim.run(
            sim.steps,
            progress=not args.quiet,
            stop_at=args.stop_at,
            verify=args.verify,
        )
        fig = sim.figure()
        last = sim.curve[-1]
        _print_stop(sim, args.stop_at, args.verify)
        print(
            f"{sim.step} grasps, {sim.session.successes} successes, "
            f"{len(sim.session.grasps)} poses; bound p_lower = {last['p_lower']:.3f}, "
            f"{_rate(sim)} {last['performance']:.3f}"
            + (f", gap {last['gap']:.3f}" if "gap" in last else "")
        )
        print(f"wrote {args.out} (session, curve.jsonl, {fig.name})")
        if sim.session.successes == 0:
            print(
                f"warning: no success in {sim.step} grasp attempts: the learning "
                "curve and the bounds say nothing about the object's grasps; check "
                "the object's size (--units), its problem file and its poses",
                file=sys.stderr,
            )
    finally:
        sim.close()
    return 0
