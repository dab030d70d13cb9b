"""The simulated online loop against the batched engine, on one problem.

Online: R sessions (seeds 0..R-1) driven by the simulated robot with the true pose
given and the problem's own reservoirs and prior (``given_poses``): the robot
executes each asked grasp with the perturbed physics, drops or topples the object
by λ and the topple matrix, and the gap Σ_s λ_s (p*_s − p[s, π_t(s)]) is read
from the problem's table p every ``every`` steps. Engine:
:func:`legs_jax.runtime.run` on the same problem, trial, method and
hyperparameters (its rewards are draws from the table p).

Agreement (the tolerance of the test and of the table written here): at every
recorded step the mean gaps differ by at most ``3 · SE + SLACK`` (SE the standard
error of the difference of the two means; ``SLACK`` = 0.02 allows for the table p
being an estimate from the build's perturbed executions, while the robot's
successes come from fresh ones), and a two-sample Kolmogorov-Smirnov test of the
final gaps does not reject at level 0.01.

With ``recognition`` the same is run with depth images, pose recognition and
observed reservoirs (the gap then uses estimated p, see
:mod:`legs_jax.online.simulate`), for the cost of recognition.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats

from legs_jax import runtime
from legs_jax.core import problem as problem_mod
from legs_jax.core.problem import stack
from legs_jax.online.errors import InputError
from legs_jax.online.outputs import is_results, out_file, refuse_tracked
from legs_jax.online.robot import World
from legs_jax.online.simulate import Simulation, save_figure

__all__ = [
    "SHIPPED",
    "SLACK",
    "compare",
    "is_shipped",
    "online_curves",
    "engine_curves",
]

SLACK = 0.02

# The configuration of the shipped table, results/online/agreement.md (its
# "Regenerate" line): bar_clamp built with 2 trials of 1000 grasps, and these
# arguments.
SHIPPED = {
    "object": "bar_clamp",
    "trials": 2,
    "grasps": 1000,
    "method": "legs",
    "rollouts": 24,
    "engine_rollouts": 500,
    "horizon": 400,
    "every": 50,
    "recognition_rollouts": 2,
}


def is_shipped(pb, args) -> bool:
    """Whether problem ``pb`` and the command's ``args`` are those of the shipped
    table (:data:`SHIPPED`)."""
    have = {
        "object": pb.name,
        "trials": pb.num_trials,
        "grasps": pb.num_grasps,
        **{k: getattr(args, k) for k in SHIPPED if hasattr(args, k)},
    }
    return have == SHIPPED


def online_curves(
    problem,
    *,
    method: str | None = None,
    rollouts: int,
    horizon: int,
    every: int,
    trial: int = 0,
    given_poses: bool = True,
    reservoir_size: int = 2000,
    progress=None,
) -> dict:
    """Gap curves [R, C] of the simulated loop, with timings."""
    world = World.from_problem(problem)
    curves, seconds, poses = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rollouts):
            sim = Simulation(
                Path(tmp) / f"r{r}",
                world,
                method=method,
                seed=r,
                problem=problem,
                trial=trial,
                given_poses=given_poses,
                reservoir_size=reservoir_size,
                eval_every=every,
            )
            t0 = time.perf_counter()
            # a rollout's warnings (a pose without a success) are not the
            # comparison's: the engine's rollouts meet the same poses
            sim.run(horizon, progress=False, on_step=progress, warn=_ignore)
            seconds.append((time.perf_counter() - t0) / horizon)
            curves.append([row["gap"] for row in sim.curve])
            poses.append(len(sim.session.grasps))
            steps = [row["step"] for row in sim.curve]
            sim.close()
    return {
        "steps": np.asarray(steps),
        "gap": np.asarray(curves),
        "seconds_per_step": np.asarray(seconds),
        "poses": np.asarray(poses),
    }


def engine_curves(problem, *, method, rollouts, horizon, every, trial=0, seed=0):
    """Gap curves [R, C] of the batched engine."""
    res = runtime.run(
        stack([problem]),
        method,
        object_ids=[0],
        trials=[trial],
        num_rollouts=rollouts,
        horizon=horizon,
        record_every=every,
        check_every=None,
        seed=seed,
        progress=False,
    )
    return {"steps": res.curve_steps, "gap": res.gap_curve[0, 0, 0]}


def compare(online: dict, eng: dict) -> dict:
    """Per recorded step: the two means, the difference, its bound; and the KS
    test of the final gaps."""
    assert np.array_equal(online["steps"], eng["steps"])
    a, b = online["gap"], eng["gap"]
    ma, mb = a.mean(0), b.mean(0)
    se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    bound = 3 * se + SLACK
    ks = stats.ks_2samp(a[:, -1], b[:, -1])
    return {
        "steps": online["steps"],
        "online": ma,
        "engine": mb,
        "diff": ma - mb,
        "bound": bound,
        "within": np.abs(ma - mb) <= bound,
        "ks_p": float(ks.pvalue),
        "agree": bool(np.all(np.abs(ma - mb) <= bound) and ks.pvalue > 0.01),
    }


def _ignore(_warning: str) -> None:
    pass


def regenerate_line(args, shipped: bool) -> str:
    """The table's "Regenerate" line: the command that made it, with the problem
    path as given, preceded by the reduced build for the shipped table."""
    build = (
        f"`python -m precompute --object {SHIPPED['object']} --trials "
        f"{SHIPPED['trials']} --grasps {SHIPPED['grasps']}` (a reduced build), then "
        if shipped
        else ""
    )
    return (
        f"Regenerate: {build}`python -m legs_jax.online agreement --problem "
        f"{args.problem} --method {args.method} --rollouts {args.rollouts} "
        f"--engine-rollouts {args.engine_rollouts} --horizon {args.horizon} "
        f"--every {args.every} --recognition-rollouts {args.recognition_rollouts}`."
    )


def _where() -> str:
    from legs_jax._machine import machine

    m = machine()
    return f"{m['cpu']}, {m['isa']}"


def _fmt(x) -> str:
    return f"{x:.3f}"


def main(args) -> int:
    """``python -m legs_jax.online agreement``: the table and figure."""
    from tqdm.auto import tqdm

    try:
        pb = problem_mod.load(args.problem)
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read problem file {args.problem}: {e}") from None
    for name in ("rollouts", "horizon", "every", "recognition_rollouts"):
        if getattr(args, name) < (0 if name == "recognition_rollouts" else 1):
            raise InputError(f"--{name.replace('_', '-')} is too small")
    shipped = is_shipped(pb, args)
    out = out_file(args.out, "agreement.md", shipped)
    refuse_tracked(
        [out, out.with_suffix(".png")], args.overwrite or (shipped and is_results(out))
    )
    total = (args.rollouts + args.recognition_rollouts) * args.horizon
    bar = None if args.quiet else tqdm(total=total, unit="grasp", desc="online")
    tick = None if bar is None else (lambda _sim: bar.update(1))
    run = dict(method=args.method, horizon=args.horizon, every=args.every)
    t0 = time.perf_counter()
    eng = engine_curves(pb, rollouts=args.engine_rollouts, **run)
    t_eng = time.perf_counter() - t0
    on = online_curves(pb, rollouts=args.rollouts, progress=tick, **run)
    rec = None
    if args.recognition_rollouts:
        rec = online_curves(
            pb,
            rollouts=args.recognition_rollouts,
            given_poses=False,
            progress=tick,
            **run,
        )
    if bar is not None:
        bar.close()
    c = compare(on, eng)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [
        f"# The online loop against the batched engine: {pb.name}, {args.method}",
        "",
        regenerate_line(args, shipped),
        "",
        f"Problem: {pb.name}, {pb.num_real_poses} poses, K = {pb.num_grasps} grasps, "
        f"trial 0; build parameters {pb.meta.get('params')}.",
        "",
        f"Online: {args.rollouts} sessions (seeds 0..{args.rollouts - 1}) against the "
        "simulated robot, true pose given, the problem's reservoirs and prior; "
        "outcomes from the perturbed physics. Engine: "
        f"{args.engine_rollouts} rollouts of `runtime.run` (outcomes drawn from the "
        "table p). Gap Δ_t from the table p in both.",
        "",
        "Agreement: |difference of the means| ≤ 3·SE + "
        f"{SLACK} at every step, and the KS test of the final gaps does not reject "
        "at 0.01.",
        "",
        "| step | online mean gap | engine mean gap | difference | allowed |",
        "|---:|---:|---:|---:|---:|",
    ]
    for i, s in enumerate(c["steps"]):
        lines.append(
            f"| {s} | {_fmt(c['online'][i])} | {_fmt(c['engine'][i])} | "
            f"{c['diff'][i]:+.3f} | {_fmt(c['bound'][i])} |"
        )
    lines += [
        "",
        f"KS test of the final gaps: p = {c['ks_p']:.3f}. "
        f"**{'Agree' if c['agree'] else 'Do not agree'}.**",
        "",
        f"Time per simulated step (given poses; ask, tell with its fsync, the "
        f"physics): median {1000 * np.median(on['seconds_per_step']):.1f} ms. "
        f"Engine: {t_eng:.1f} s for all its rollouts, compile included. "
        f"Wall times, measured on {_where()} ({os.cpu_count()} CPUs).",
    ]
    if rec is not None:
        lines += [
            "",
            "## With recognition and observed reservoirs",
            "",
            f"{args.recognition_rollouts} sessions with 640×480 depth images, pose "
            "recognition and reservoirs of 2000 grasps sampled on the first image of "
            "each pose, scored by the learned prior on the session's own image "
            "(the problem's network, not the problem's q). "
            "The gap uses the problem's p*_s and the true success probability of the "
            "recommended grasp estimated from 50 perturbed executions (0 for a pose "
            "not seen yet, whereas the engine starts from the prior's best grasp of "
            "every pose).",
            "",
            "| step | recognition mean gap | given poses mean gap |",
            "|---:|---:|---:|",
        ]
        for i, s in enumerate(rec["steps"]):
            lines.append(
                f"| {s} | {_fmt(rec['gap'][:, i].mean())} | {_fmt(c['online'][i])} |"
            )
        lines += [
            "",
            "The recognition rows are not an agreement check: their reservoirs are "
            "other grasps (sampled on the images) ranked by the prior's scores on "
            "those images, so their gap, measured against the best grasp of the "
            "problem's own reservoir, can fall lower than the engine's, even below 0.",
            "",
            "Cost of recognition: median "
            f"{1000 * np.median(rec['seconds_per_step']):.0f} ms a step (rendering "
            "the image included) against "
            f"{1000 * np.median(on['seconds_per_step']):.0f} ms with the pose "
            f"given; poses created: {rec['poses'].tolist()} (the object has "
            f"{pb.num_real_poses}).",
        ]
    out.write_text("\n".join(lines) + "\n")
    fig = _figure(c, rec, pb.name, args.method, out.with_suffix(".png"))
    print("\n".join(lines))
    print(f"wrote {out} and {fig}")
    if args.out is None and not shipped:
        print(
            "(not results/online/agreement.md: the shipped table is bar_clamp built "
            "with 2 trials of 1000 grasps and the arguments of its Regenerate line; "
            "--out names another place)"
        )
    return 0


def _figure(c, rec, name, method, path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(c["steps"], c["engine"], label="batched engine")
    ax.plot(c["steps"], c["online"], "o-", label="online loop, pose given")
    ax.fill_between(
        c["steps"], c["engine"] - c["bound"], c["engine"] + c["bound"], alpha=0.2,
        label="agreement tolerance",
    )  # fmt: skip
    if rec is not None:
        ax.plot(c["steps"], rec["gap"].mean(0), "s--", label="online, recognition")
    ax.set_xlabel("grasp attempts")
    ax.set_ylabel("mean gap Δ_t")
    return save_figure(fig, ax, f"{name}: {method}", path)
