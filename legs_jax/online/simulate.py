"""The simulated loop: a :class:`Session` driven by a :class:`SimRobot`.

Every random draw of the robot at step t comes from its own generator seeded by
(seed, t, stream), so that the robot's whole history is a function of the
outcomes in the session's log: ``--resume`` reopens the session (which replays
its log) and replays the robot's drops and topples from the same outcomes, then
continues exactly where a run without the kill would have been.

The learning curve is evaluated every ``eval_every`` steps and appended to
``curve.jsonl``: the Dirichlet bound p̂_ℓ, and the true expected success rate of
the current recommendations, Σ_s λ_s p(π(s)), with the gap to Σ_s λ_s p*_s when
the best grasps are known (a problem file). With the problem's reservoirs
(``given_poses``) p is the problem's own table (as in the batched engine); with
recognition p is estimated from ``EVAL_SAMPLES`` perturbed executions of the
recommended grasp of the session pose that recognition assigned the true pose to
most often (0 for a true pose not seen yet).
"""

from __future__ import annotations

import json
import os
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

from legs_jax.online.errors import InputError, StateError
from legs_jax.online.robot import SimRobot, World
from legs_jax.online.session import Session
from legs_jax.online.store import atomic_write

__all__ = ["EVAL_SAMPLES", "Simulation", "default_eval_every", "save_figure"]


def _check_stop_at(stop_at) -> None:
    if stop_at is not None and (
        isinstance(stop_at, bool)
        or not isinstance(stop_at, (int, float))
        or not 0.0 <= stop_at <= 1.0
    ):
        raise InputError(f"the stopping threshold must be in [0, 1], got {stop_at!r}")


def _plot_ours(ax, curve) -> None:
    """Our bound on the learning curve, and the stop (ρ_min reached) if any."""
    rows = [r for r in curve if "p_lower_ours" in r]
    if rows:
        ax.plot(
            [r["step"] for r in rows],
            [r["p_lower_ours"] for r in rows],
            ":",
            label="our bound (stops on it)",
            marker="o",
            markersize=2.5,
        )
    for r in curve:
        if r.get("stop"):
            ax.axvline(r["step"], color="k", lw=1.0, alpha=0.6)
            ax.annotate(
                f"stop: bound {r['p_lower_ours']:.2f} ≥ ρ_min {r['rho_min']:.2f},"
                f" success rate {r['performance']:.2f}",
                (r["step"], 0.04),
                fontsize=7,
                ha="right",
                rotation=90,
                va="bottom",
            )


EVAL_SAMPLES = 50
_RENDER, _EXECUTE, _MOVE, _EVAL = 0, 1, 2, 3


class Simulation:
    """A simulated session in ``folder`` (created or resumed)."""

    def __init__(
        self,
        folder,
        world: World,
        *,
        method: str | None = None,
        seed: int = 0,
        resume: bool = False,
        problem=None,
        trial: int = 0,
        given_poses: bool = False,
        hparams=None,
        max_poses: int = 24,
        reservoir_size: int = 2000,
        eval_every: int | None = None,
        steps: int | None = None,
        prior: str = "learned",
        bound_replicates: int = 0,
    ):
        self.folder = Path(folder)
        self.world = world
        self.seed = seed
        self.problem = problem
        self.trial = trial
        self.robot = SimRobot(world, np.random.default_rng(0))
        if given_poses and problem is None:
            raise InputError("given poses need a problem file (its reservoirs)")
        self.given = given_poses
        if resume:
            self.session = Session.open(self.folder)
            try:
                info = json.loads((self.folder / "simulation.json").read_text())
            except (OSError, ValueError):
                self.session.close()
                raise StateError(
                    f"{self.folder} holds a session but not a simulated run (no "
                    "readable simulation.json); it cannot be resumed here"
                ) from None
            if info.get("object") != world.name:
                self.session.close()
                raise StateError(
                    f"{self.folder} is a run of {info.get('object')!r}, not "
                    f"{world.name!r}"
                )
            self.seed = seed = int(info["seed"])
            self.trial = trial = int(info["trial"])
            self.given = bool(info["given_poses"])
            # the run's own length and curve step, unless given anew
            self.steps = int(steps if steps is not None else info.get("steps", 1000))
            self.eval_every = int(
                eval_every
                if eval_every is not None
                else info.get("eval_every", default_eval_every(self.steps))
            )
            if (info.get("steps"), info.get("eval_every")) != (
                self.steps,
                self.eval_every,
            ):
                info.update(steps=self.steps, eval_every=self.eval_every)
                atomic_write(
                    self.folder / "simulation.json", (json.dumps(info) + "\n").encode()
                )
        else:
            given = None
            if given_poses:
                given = _problem_poses(problem, trial)
            self.session = Session.create(
                self.folder,
                method,
                hparams=hparams,
                seed=seed,
                max_poses=max_poses,
                reservoir_size=reservoir_size,
                given_poses=given,
                prior=prior,
                bound_replicates=bound_replicates,
                note=f"simulated robot: {world.name}",
            )
            self.steps = int(steps if steps is not None else 1000)
            self.eval_every = int(
                eval_every if eval_every is not None else default_eval_every(self.steps)
            )
            info = {
                "object": world.name,
                "seed": seed,
                "trial": trial,
                "given_poses": bool(given_poses),
                "steps": self.steps,
                "eval_every": self.eval_every,
            }
            atomic_write(
                self.folder / "simulation.json", (json.dumps(info) + "\n").encode()
            )
        self.truth: dict[int, Counter] = {}  # session pose -> true poses seen
        self.frames: dict[int, np.ndarray] = {}  # session pose -> pose frame map
        self._replay()
        self.curve = self._read_curve()
        self.stopped = None  # the evaluation row a run stopped at (stop_at)

    # ----------------------------------------------------------------- replay
    def _rng(self, t: int, stream: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, t, stream])

    def _replay(self) -> None:
        self.robot.rng = self._rng(0, _MOVE)
        self.robot.place()
        for r in self.session.store.records:
            if r["type"] == "observe":
                self._note(r)
            elif r["type"] == "tell":
                self.robot.rng = self._rng(int(r["step"]), _MOVE)
                self.robot.transition(bool(r["success"]))

    def _note(self, r: dict) -> None:
        s = int(r["pose"])
        self.truth.setdefault(s, Counter())[self.robot.pose] += 1
        if s not in self.frames:
            # session pose frame -> true pose frame, from its first sighting
            T = np.asarray(r["transform"]).reshape(4, 4)
            self.frames[s] = np.linalg.inv(self.robot.placement) @ np.linalg.inv(T)

    def _read_curve(self) -> list[dict]:
        path = self.folder / "curve.jsonl"
        out = []
        if path.is_file():
            for line in path.read_text().splitlines():
                try:
                    row = json.loads(line)
                except json.JSONDecodeError:
                    break  # a torn last line
                if row["step"] <= self.session.step:
                    out.append(row)
        body = "".join(json.dumps(r) + "\n" for r in out)
        atomic_write(path, body.encode())
        return out

    # ------------------------------------------------------------------ steps
    @property
    def step(self) -> int:
        return self.session.step

    def run_step(self) -> bool:
        """One observe → ask → execute → tell; the outcome."""
        t = self.session.step + 1
        ses, rob = self.session, self.robot
        if self.given:
            r = ses.observe(pose=rob.pose)
        else:
            rob.rng = self._rng(t, _RENDER)
            depth = rob.render()
            r = ses.observe(depth, rob.intrinsics.to_dict())
        self._note(ses.store.records[-1])
        del r
        if ses.loop.n_valid(ses.pose) == 0:  # no grasp: a failed attempt
            raise InputError(f"pose {ses.pose} has no grasp; cannot continue")
        g = ses.ask()
        rob.rng = self._rng(t, _EXECUTE)
        if self.given:
            ok = rob.success(np.asarray(g["center_table"]), np.asarray(g["axis_table"]))
        else:
            c, a = rob.to_pose_frame(
                np.asarray(g["center_table"]), np.asarray(g["axis_table"])
            )
            ok = rob.success(c, a)
        ses.tell(bool(ok))
        rob.rng = self._rng(t, _MOVE)
        rob.transition(bool(ok))
        return bool(ok)

    def evaluate(self) -> dict:
        """The curve point at the current step (see the module docstring)."""
        ses = self.session
        lam = self.world.landing
        P = len(lam)
        perf = np.zeros(P)
        if self.given:
            rec = ses.loop.recommendation()
            keep = np.flatnonzero(self.problem.pose_valid)
            p = self.problem.robustness[self.trial][keep]
            for s in range(P):
                if rec[s] >= 0:
                    perf[s] = p[s, rec[s]]
        else:
            # the session pose most often assigned to each true pose
            best: dict[int, tuple[int, int]] = {}
            for sp, c in self.truth.items():
                for true, n in c.items():
                    if n > best.get(true, (0, -1))[0]:
                        best[true] = (n, sp)
            for true, (_, sp) in best.items():
                r = ses.recommended(sp)
                if r is None:
                    continue
                F = self.frames[sp]
                c = F[:3, :3] @ r["center"] + F[:3, 3]
                a = F[:3, :3] @ r["axis"]
                keep = self.robot.pose
                self.robot.pose = true
                self.robot.rng = self._rng(ses.step, _EVAL)
                perf[true] = self.robot.success(c, a, samples=EVAL_SAMPLES)
                self.robot.pose = keep
        b = ses.bound()
        row = {
            "step": ses.step,
            "performance": float(lam @ perf),
            "p_lower": b["p_lower"],
            "p_lower_ours": b["p_lower_ours"],
            "poses": len(ses.grasps),
            "successes": ses.successes,
        }
        if self.problem is not None:
            pb = self.problem
            p_star = np.where(pb.valid[self.trial], pb.robustness[self.trial], 0).max(
                -1
            )
            keep = np.flatnonzero(pb.pose_valid)
            row["gap"] = float(lam @ p_star[keep] - row["performance"])
        return row

    def _record(self, row: dict) -> None:
        self.curve.append(row)
        with open(self.folder / "curve.jsonl", "a") as fh:
            fh.write(json.dumps(row) + "\n")
            fh.flush()
            os.fsync(fh.fileno())

    def run(
        self,
        steps: int,
        progress: bool = True,
        on_step=None,
        stop_at=None,
        warn: Callable[[str], None] | None = None,
        verify: bool = False,
    ) -> None:
        """Run until the session has ``steps`` outcomes, or with ``stop_at`` (ρ_min)
        until an evaluation finds our bound ``p_lower_ours`` ≥ ρ_min (the row is
        marked ``"stop": true`` and kept in ``self.stopped``). With ``verify`` such
        an evaluation opens a verification phase instead (:meth:`Session.verify`):
        the robot tries the frozen recommendations, and the run stops where the
        test certifies ρ_min (that step's row is marked ``"stop": true``) or goes
        on exploring where it refutes it. The session's warnings
        (:meth:`Session.take_warnings`) go to ``warn``, by default to stderr as
        lines beginning ``warning:``."""
        _check_stop_at(stop_at)
        if verify and stop_at is None:
            raise InputError("verified stopping needs a threshold (stop_at)")
        if verify and not 0.0 < stop_at < 1.0:
            raise InputError(f"a verified threshold must be in (0, 1), got {stop_at}")
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(
                total=steps,
                initial=self.step,
                desc=f"{self.session.method}",
                unit="grasp",
            )
        if not self.curve or self.curve[0]["step"] != 0:
            if self.step == 0:
                self._record(self.evaluate())
        while self.step < steps:
            self.run_step()
            for w in self.session.take_warnings():
                if warn is not None:
                    warn(w)
                elif bar is not None:
                    bar.write(f"warning: {w}", file=sys.stderr)
                else:
                    print(f"warning: {w}", file=sys.stderr)
            certified = verify and self.session.stopped is not None
            if self.step % self.eval_every == 0 or self.step == steps or certified:
                row = self.evaluate()
                reached = stop_at is not None and row["p_lower_ours"] >= stop_at
                stop = certified or (reached and not verify)
                if verify and reached and not certified:
                    self.session.verify(float(stop_at))
                if verify:
                    row["verification"] = self.session.verification_state()
                if stop:
                    row.update(stop=True, rho_min=float(stop_at))
                    self.stopped = row
                self._record(row)
                if stop:
                    break
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    poses=len(self.session.grasps), ok=self.session.successes
                )
            if on_step is not None:
                on_step(self)
        if bar is not None:
            bar.close()

    def figure(self, path=None) -> Path:
        """The learning curve (PNG)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        path = Path(path or self.folder / "learning_curve.png")
        steps = [r["step"] for r in self.curve]
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        # markers: each point is a measurement, the lines only join them
        mark = {"marker": "o", "markersize": 2.5}
        ax.plot(
            steps,
            [r["performance"] for r in self.curve],
            label=(
                "true success rate of π_t"
                if self.given
                else f"success rate of π_t (estimated, {EVAL_SAMPLES} executions)"
            ),
            **mark,
        )
        if self.curve and "gap" in self.curve[0]:
            ax.plot(steps, [r["gap"] for r in self.curve], label="gap Δ_t", **mark)
        ax.plot(
            steps,
            [r["p_lower"] for r in self.curve],
            "--",
            label="Dirichlet bound p̂_ℓ",
            **mark,
        )
        _plot_ours(ax, self.curve)
        ax.set_xlabel("grasp attempts")
        ax.set_ylim(0, 1)
        mode = (
            "problem reservoirs, pose given"
            if self.given
            else "recognition + observed reservoirs"
        )
        title = f"{self.world.name}: {self.session.method} ({mode})"
        return save_figure(fig, ax, title, path)

    def close(self) -> None:
        self.session.close()


def default_eval_every(steps: int) -> int:
    """The curve step when none is given: 50 points over the run, at most every
    100 steps (a curve point with recognition costs ``EVAL_SAMPLES`` executions
    per pose)."""
    return max(1, min(100, steps // 50))


def _problem_poses(problem, trial: int) -> dict[int, dict[str, np.ndarray]]:
    if not 0 <= trial < problem.num_trials:
        raise InputError(
            f"trial {trial} out of range: the problem has {problem.num_trials}"
        )
    out = {}
    for i, s in enumerate(np.flatnonzero(problem.pose_valid)):
        out[i] = {
            "center": problem.grasp_center[trial, s],
            "axis": problem.grasp_axis[trial, s],
            "width": problem.grasp_width[trial, s],
            "q": problem.prior[trial, s],
            "valid": problem.valid[trial, s],
        }
    return out


def save_figure(fig, ax, title: str, path):
    """Title, legend and grid on ``ax``; ``fig`` written to ``path`` and closed."""
    import matplotlib.pyplot as plt

    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
