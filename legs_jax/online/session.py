"""The online session: observe → ask → tell, and the stopping bound.

A :class:`Session` runs one exploration method on one object in front of a robot:

- :meth:`Session.observe` (depth image, intrinsics) recognises the object's stable
  pose (:mod:`legs_jax.online.recognition`); a new pose is cached and gets a
  reservoir of grasps sampled on the image (:mod:`legs_jax.online.sampler`),
  scored by the learned prior (:func:`legs_jax.online.sampler.learned_prior`).
- :meth:`Session.ask` returns the grasp to execute, mapped from the pose's frame
  through the recognised alignment into the table and camera frames.
- :meth:`Session.tell` records the outcome: the method learns it, and it is in the
  log on disk before the call returns.
- :meth:`Session.bound` is the Dirichlet lower bound p̂_ℓ of the paper on the success
  rate of the current recommendations (the paper's, ``p_lower``) and ours
  (``p_lower_ours``, :mod:`legs_jax.core.stopping`, the one to stop on), and whether
  each exceeds ρ_min.

With ``given_poses`` (a problem file's reservoirs) the caller names the pose
(``observe(pose=s)``) and the grasps are the problem's, in the pose frame; this
is the loop of the batched engine with the world outside it (tests and the
agreement check).

Drop counts c_s follow the engine: the first landing and every landing after a
success count; a topple (after a failure) only marks the pose observed.

Warnings (:meth:`Session.take_warnings`, once per process each): a pose with no
success in :data:`NO_SUCCESS_ATTEMPTS` attempts (its grasps may all fail: its
recommendation and the bound then mean little), and, with recognition, one pose
only after :data:`ONE_POSE_STEPS` steps (an object with a single stable pose, or
recognition taking distinct poses for one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from legs_jax.core import keys as keys_mod
from legs_jax.core import verify as verify_mod
from legs_jax.core.constants import DELTA_STOP
from legs_jax.online import recognition as rec_mod
from legs_jax.online import sampler as sampler_mod
from legs_jax.online._adapter import Loop, check_hparams, default_method
from legs_jax.online.camera import (
    Intrinsics,
    check_camera_pose,
    check_depth,
    default_camera_pose,
)
from legs_jax.online.errors import InputError, OrderError, StateError
from legs_jax.online.store import Store

__all__ = [
    "Session",
    "DEFAULT_MAX_POSES",
    "DEFAULT_RESERVOIR",
    "NO_SUCCESS_ATTEMPTS",
    "ONE_POSE_STEPS",
]

DEFAULT_MAX_POSES = 24
DEFAULT_RESERVOIR = 2000
# grasp attempts in one pose without a success after which the session warns
NO_SUCCESS_ATTEMPTS = 50
# steps after which a session with recognition that has seen one pose only warns
ONE_POSE_STEPS = 100
SESSION_OBJECT_ID = 0  # rollout keys: key(seed) → object 0 → trial 0 → rollout 0


def _rollout_key(seed: int):
    return keys_mod.rollout_key(seed, SESSION_OBJECT_ID, 0, 0)


class Session:
    """One online session over a folder (use :meth:`create` or :meth:`open`)."""

    def __init__(self, store: Store, prior: Callable | None = None):
        cfg = store.config
        self.store = store
        self.method = cfg["method"]
        self.max_poses = int(cfg["max_poses"])
        self.reservoir_size = int(cfg["reservoir_size"])
        self.seed = int(cfg["seed"])
        self.camera_pose = np.asarray(cfg["camera_pose"], np.float64)
        self.given = bool(cfg.get("given_poses", False))
        # a callable, or the name of the prior the session was created with
        self._prior = (
            prior if prior is not None else cfg.get("prior", sampler_mod.DEFAULT_PRIOR)
        )
        self.loop = Loop(
            self.method,
            self.max_poses,
            self.reservoir_size,
            cfg["hparams"],
            _rollout_key(self.seed),
            int(cfg.get("bound_replicates", 0)),
        )
        self.library = rec_mod.PoseLibrary(seed=self.seed)
        self.grasps: list[dict[str, np.ndarray]] = []  # per pose, pose frame
        self.counts = np.zeros(self.max_poses, np.int64)
        self.observed = np.zeros(self.max_poses, bool)
        self.step = 0
        self.successes = 0
        self.pose: int | None = None  # current pose
        self.transform = np.eye(4)  # table -> current pose frame
        self._landing = True  # the next observation is a landing (counts)
        self._landing_pose: int | None = None
        self._pending: dict | None = None
        self.attempts = np.zeros(self.max_poses, np.int64)  # per pose
        self.pose_successes = np.zeros(self.max_poses, np.int64)
        self._warned: set = set()
        self._warnings: list[str] = []
        # verified stopping (legs_jax.core.verify): the run's test, its last
        # outcome and, once it certified, the stop
        self.verification: verify_mod.Verification | None = None
        self._verdict: str | None = None
        self._phase_start = 0
        self.stopped: dict | None = None
        for r in store.records:
            self._apply(r, replay=True)

    # ------------------------------------------------------------ construction
    @classmethod
    def create(
        cls,
        folder,
        method: str | None = None,
        *,
        hparams: Mapping | None = None,
        seed: int = 0,
        max_poses: int = DEFAULT_MAX_POSES,
        reservoir_size: int = DEFAULT_RESERVOIR,
        camera_pose=None,
        given_poses: Mapping[int, Mapping[str, np.ndarray]] | None = None,
        prior: Callable | None = None,
        bound_replicates: int = 0,
        note: str = "",
    ) -> Session:
        """A new session in ``folder`` (which must not hold one).

        Args:
          method: a registered method that does not read ground truth.
          hparams: overrides of the method's own defaults (``method.hparams``,
            e.g. s, prior_offset, δ, γ, k, n for LEGS).
          seed: seeds the method's draws (the engine's key streams).
          max_poses: pose capacity (a static shape).
          reservoir_size: grasps per new pose's reservoir (K).
          camera_pose: 4×4 camera → table transform (default: straight down from
            0.7 m over the table origin).
          given_poses: pose index → arrays ``center`` [K, 3], ``axis`` [K, 3],
            ``width`` [K], ``q`` [K], ``valid`` [K] (pose frame): the poses are
            named by the caller and recognition is off.
          prior: ``"learned"`` (default: :func:`legs_jax.online.sampler.learned_prior`,
            or the geometric stand-in, with a warning, where its weights are
            missing), ``"geometric"`` (the stand-in) or a function
            ``f(grasps, view) -> q [K]`` (give it again to :meth:`open`).
          bound_replicates: our stopping bound's fit of each pose's G_s: 0 (the
            default) the plug-in fit; R > 0 the posterior averaged over R
            Bayesian-bootstrap fits, more often valid on hard objects at about
            four times the cost of a check (docs: Stopping bounds). Kept by a
            resumed session.
        """
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise InputError(f"seed must be an integer >= 0, got {seed!r}")
        if prior is None:
            prior = sampler_mod.DEFAULT_PRIOR
        if isinstance(prior, str) and prior not in sampler_mod.PRIORS:
            raise InputError(
                f"prior must be one of {', '.join(sampler_mod.PRIORS)} or a "
                f"function, got {prior!r}"
            )
        for name, v, lo in (
            ("max_poses", max_poses, 1),
            ("reservoir_size", reservoir_size, 1),
            ("bound_replicates", bound_replicates, 0),
        ):
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise InputError(f"{name} must be an integer >= {lo}, got {v!r}")
        K = reservoir_size
        if given_poses is not None:
            K = max(len(np.asarray(g["valid"])) for g in given_poses.values())
            max_poses = max(max_poses, max(given_poses) + 1)
        method = method or default_method()
        hp = check_hparams(method, hparams, K)
        cam = default_camera_pose() if camera_pose is None else camera_pose
        cam = check_camera_pose(cam)
        config = {
            "method": method,
            "hparams": hp,
            "seed": seed,
            "max_poses": int(max_poses),
            "reservoir_size": int(K),
            "camera_pose": cam.tolist(),
            "given_poses": given_poses is not None,
            "prior": prior if isinstance(prior, str) else "custom",
            "bound_replicates": int(bound_replicates),
            "note": note,
        }
        store = Store.create(folder, config)
        if given_poses is not None:
            for s, g in sorted(given_poses.items()):
                arrays = {
                    k: np.asarray(g[k])
                    for k in ("center", "axis", "width", "q", "valid")
                }
                name, sha = store.write_pose(int(s), arrays)
                store.append(
                    {"type": "given_pose", "pose": int(s), "file": name, "sha256": sha}
                )
        return cls(store, prior)

    @classmethod
    def open(cls, folder, prior: Callable | None = None) -> Session:
        """Resume the session in ``folder`` with every recorded outcome."""
        return cls(Store.open(folder), prior)

    def close(self) -> None:
        self.store.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def prior(self) -> Callable:
        """The prior that scores new poses' grasps."""
        if self._prior == "custom":
            raise StateError(
                "this session was created with a prior function of its own: give "
                "it again, Session.open(folder, prior=f)"
            )
        if isinstance(self._prior, str):
            self._prior = sampler_mod.default_prior(self._prior)
        return self._prior

    # ------------------------------------------------------------ the records
    def _apply(self, r: dict, replay: bool) -> None:
        kind = r.get("type")
        if kind == "given_pose":
            arrays = self.store.read_pose(r["file"], r["sha256"])
            self._set_pose(int(r["pose"]), arrays)
        elif kind == "observe":
            s = int(r["pose"])
            if r.get("new"):
                arrays = self.store.read_pose(r["file"], r["sha256"])
                if "cloud" in arrays:
                    j = self.library.add(arrays["cloud"])
                    if j != s:
                        raise StateError(
                            f"{self.store.folder}: pose files out of order"
                        )
                self._set_pose(s, arrays)
            if s >= self.max_poses or (s >= len(self.grasps) and not self.given):
                raise StateError(f"{self.store.folder}: the log names unknown pose {s}")
            self.observed[s] = True
            if self._landing:
                if self._landing_pose is not None:
                    self.counts[self._landing_pose] -= 1
                self.counts[s] += 1
                self._landing_pose = s
            self.pose = s
            self.transform = np.asarray(r["transform"], np.float64).reshape(4, 4)
            self._pending = None
        elif kind == "verify":
            rho, delta = float(r["rho_min"]), float(r["delta"])
            if self.verification is None:
                self.verification = verify_mod.Verification(rho, delta)
            self.verification.start()
            self._verdict = None
            self._phase_start = self.step
        elif kind == "tell":
            self.step = int(r["step"])
            if r.get("verify"):
                # an attempt of the frozen recommendations: it counts as a step
                # and a landing, and goes to the test, not to the method
                if not self.verifying:
                    raise StateError(
                        f"{self.store.folder}: the log has a verification attempt "
                        "outside a verification phase"
                    )
                # Only an attempt right after a landing (a drop: the pose drawn
                # from λ) is a sample of the recommendations' true performance;
                # after a failure the object lies where it toppled, and those
                # attempts count as steps but not in the test.
                if self._landing_pose is not None:
                    self._verdict = self.verification.record(bool(r["success"]))
                else:
                    self._verdict = None
                if self._verdict == verify_mod.CERTIFIED:
                    self.stopped = {
                        "step": self.step,
                        "rho_min": self.verification.rho,
                        "phase": self.verification.phase,
                        "attempts": self.verification.attempts,
                        "successes": self.verification.successes,
                        "phase_steps": self.step - self._phase_start,
                    }
            else:
                self.loop.tell(
                    int(r["pose"]),
                    int(r["grasp"]),
                    int(r["slot"]),
                    bool(r["success"]),
                    self.step,
                )
            self.successes += bool(r["success"])
            self.attempts[int(r["pose"])] += 1
            self.pose_successes[int(r["pose"])] += bool(r["success"])
            self._landing = bool(r["success"])
            self._landing_pose = None
            self._pending = None
            if not replay:
                self._check(int(r["pose"]))
        else:
            raise StateError(f"{self.store.folder}: unknown log record type {kind!r}")

    def _check(self, s: int) -> None:
        """Queue the warnings that the outcome just told makes due (each once)."""
        n = int(self.attempts[s])
        if (
            n >= NO_SUCCESS_ATTEMPTS
            and self.pose_successes[s] == 0
            and ("pose", s) not in self._warned
        ):
            self._warned.add(("pose", s))
            self._warnings.append(
                f"pose {s} has had no success in {n} grasp attempts (the session "
                f"warns after {NO_SUCCESS_ATTEMPTS}): its grasps may all fail, and "
                "its recommendation and the stopping bound then mean little"
            )
        if (
            not self.given
            and self.step >= ONE_POSE_STEPS
            and len(self.grasps) == 1
            and "one pose" not in self._warned
        ):
            self._warned.add("one pose")
            self._warnings.append(
                f"recognition has seen one pose only in {self.step} steps (the "
                f"session warns after {ONE_POSE_STEPS}): either the object rests "
                "in a single stable pose, or recognition takes distinct poses for "
                "one, and the recommendation and the bound mix them"
            )

    def take_warnings(self) -> list[str]:
        """The warnings due since the last call (each is given once per
        process): see the module docstring."""
        out, self._warnings = self._warnings, []
        return out

    def _set_pose(self, s: int, arrays: dict) -> None:
        while len(self.grasps) <= s:
            self.grasps.append({})
        self.grasps[s] = arrays
        valid = np.asarray(arrays["valid"], bool)
        K = self.reservoir_size
        q = np.zeros(K, np.float32)
        v = np.zeros(K, bool)
        q[: len(valid)] = np.asarray(arrays["q"], np.float32)
        v[: len(valid)] = valid
        self.loop.set_reservoir(s, q, v)

    # -------------------------------------------------------------- the calls
    def observe(self, depth=None, intrinsics=None, *, pose: int | None = None) -> dict:
        """Recognise the object's pose from a depth image (metres, [H, W]) and its
        intrinsics (fx, fy, cx, cy, width, height); with ``given_poses`` name the
        pose instead. Returns the pose index, whether it is new, the match
        fraction and the alignment (yaw about the vertical, translation)."""
        if self.given:
            if depth is not None or intrinsics is not None:
                raise InputError("this session's poses are given: observe(pose=s)")
            if not isinstance(pose, int) or isinstance(pose, bool):
                raise InputError(f"pose must be an integer, got {pose!r}")
            if not 0 <= pose < len(self.grasps) or not self.grasps[pose]:
                raise InputError(f"pose {pose} is not one of the given poses")
            rec = {
                "type": "observe",
                "pose": pose,
                "new": False,
                "transform": np.eye(4).ravel().tolist(),
                "fraction": 1.0,
            }
            self._apply(self.store.append(rec), replay=False)
            return {
                "pose": pose,
                "new": False,
                "fraction": 1.0,
                "yaw_deg": 0.0,
                "translation": [0.0, 0.0, 0.0],
                "grasps": self.loop.n_valid(pose),
            }
        if pose is not None:
            raise InputError("this session recognises poses from depth images")
        if intrinsics is None or depth is None:
            raise InputError("observe needs a depth image and its intrinsics")
        intr = Intrinsics.from_any(intrinsics)
        d = check_depth(depth, intr)
        pts, _ = rec_mod.object_cloud(d, intr, self.camera_pose)
        match, cloud = self.library.recognise(pts)
        record = {
            "type": "observe",
            "fraction": round(match.fraction, 4),
            "transform": match.transform.ravel().tolist(),
            "points": len(pts),
        }
        if match.pose is None:
            s = len(self.library)
            if s >= self.max_poses:
                raise StateError(
                    f"a new pose would be pose {s + 1} of a session created with "
                    f"max_poses={self.max_poses}; start a session with more"
                )
            rng = np.random.default_rng([self.seed, s, 1])
            g = sampler_mod.sample_grasps(
                d, intr, self.camera_pose, self.reservoir_size, rng
            )
            view = sampler_mod.View(d, intr, self.camera_pose)
            q = np.asarray(self.prior(g, view), np.float64)
            if q.shape != (len(g),) or not np.all(np.isfinite(q)):
                raise InputError(
                    f"the prior returned shape {q.shape}; expected ({len(g)},) finite"
                )
            g = g.transformed(match.transform)
            K = self.reservoir_size
            arrays = {
                "cloud": cloud.astype(np.float32),
                "center": _pad(g.center, K),
                "axis": _pad(g.axis, K),
                "width": _pad(g.width, K),
                "q": _pad(np.clip(q, 0.0, 1.0), K),
                "valid": np.arange(K) < len(g),
            }
            name, sha = self.store.write_pose(s, arrays)
            record.update(
                pose=s,
                new=True,
                file=name,
                sha256=sha,
                prior=sampler_mod.prior_name(self.prior),
            )
        else:
            record.update(pose=int(match.pose), new=False)
        self._apply(self.store.append(record), replay=False)
        R = match.transform[:3, :3]
        out = {
            "pose": record["pose"],
            "new": record["new"],
            "fraction": record["fraction"],
            "closest_pose": match.best_pose,
            "yaw_deg": float(np.degrees(math.atan2(R[1, 0], R[0, 0]))),
            "translation": match.transform[:3, 3].tolist(),
            "grasps": self.loop.n_valid(record["pose"]),
        }
        if record["new"]:
            out["prior"] = record["prior"]
        return out

    def ask(self) -> dict:
        """The grasp to execute in the current pose: its id, the jaw centre and
        unit axis in the table and camera frames, width (m), depth (camera z of
        the centre, m) and height above the table (m). Asking again before
        ``tell`` returns the same grasp."""
        if self.pose is None:
            raise OrderError("observe the object before asking for a grasp")
        if self._pending is not None:
            return self._pending["answer"]
        s = self.pose
        if self.loop.n_valid(s) == 0:
            raise OrderError(
                f"pose {s} has no grasp in its reservoir: move the object and observe "
                "again"
            )
        t = self.step + 1
        testing = self.verifying
        if testing:  # the frozen recommendation of this pose
            grasp, slot = int(self.loop.recommendation()[s]), -1
            if grasp < 0:
                raise OrderError(
                    f"pose {s} has no recommended grasp to verify: move the object "
                    "and observe again"
                )
        else:
            grasp, slot = self.loop.select(s, t)
        g = self.grasps[s]
        inv = np.linalg.inv(self.transform)  # pose frame -> table
        c_t = inv[:3, :3] @ np.asarray(g["center"][grasp], np.float64) + inv[:3, 3]
        a_t = inv[:3, :3] @ np.asarray(g["axis"][grasp], np.float64)
        cam_inv = np.linalg.inv(self.camera_pose)
        c_c = cam_inv[:3, :3] @ c_t + cam_inv[:3, 3]
        a_c = cam_inv[:3, :3] @ a_t
        answer = {
            "step": t,
            "pose": s,
            "grasp": grasp,
            "center_table": c_t.tolist(),
            "axis_table": a_t.tolist(),
            "center_camera": c_c.tolist(),
            "axis_camera": a_c.tolist(),
            "width": float(g["width"][grasp]),
            "depth": float(c_c[2]),
            "height": float(c_t[2]),
        }
        if testing:
            answer["verify"] = True
        self._pending = {"grasp": grasp, "slot": slot, "answer": answer}
        return answer

    def pending_grasp(self) -> int | None:
        """The id of the grasp asked for and not yet told, or None."""
        return None if self._pending is None else int(self._pending["grasp"])

    def tell(self, success) -> dict:
        """Record the outcome of the asked grasp (True: the object was lifted)."""
        if not isinstance(success, (bool, np.bool_)):
            raise InputError(f"success must be true or false, got {success!r}")
        if self._pending is None:
            raise OrderError("tell without a pending ask: ask for a grasp first")
        p = self._pending
        rec = {
            "type": "tell",
            "step": self.step + 1,
            "pose": self.pose,
            "grasp": p["grasp"],
            "slot": p["slot"],
            "success": bool(success),
        }
        if p["answer"].get("verify"):
            rec["verify"] = True
        self._apply(self.store.append(rec), replay=False)
        out = {"step": self.step, "successes": self.successes}
        if rec.get("verify"):
            out["verification"] = self.verification_state()
        return out

    # ------------------------------------------------------ verified stopping
    @property
    def verifying(self) -> bool:
        """Whether a verification phase is open (asks give the frozen
        recommendations)."""
        return self.verification is not None and self.verification.active

    def verify(self, rho_min: float, delta: float = DELTA_STOP) -> dict:
        """Open a verification phase at threshold ``rho_min``
        (:mod:`legs_jax.core.verify`): until the phase ends, ``ask`` gives the
        recommended grasp of the observed pose (the recommendations are frozen:
        the outcomes go to the test, not to the method) and each ``tell`` after
        a landing (the object dropped, not toppled) adds an attempt to the test;
        the others count as steps only. The phase ends ``certified`` (stop:
        ``stopped`` holds the step) or ``refuted`` (exploration resumes; open
        another phase when the bound reaches ``rho_min`` again). A run tests one
        threshold: its phases share δ_stop = ``delta``. Calling it while a phase
        is open, or after the stop, changes nothing."""
        for name, v in (("rho_min", rho_min), ("delta", delta)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
                raise InputError(f"{name} must be a number in (0, 1), got {v!r}")
        if self.verification is not None and (
            self.verification.rho != float(rho_min)
            or self.verification.delta != float(delta)
        ):
            raise InputError(
                f"this run verifies rho_min = {self.verification.rho} at delta = "
                f"{self.verification.delta}; its phases share that level, so it "
                "cannot test another threshold (start a new session for one)"
            )
        if self.stopped is None and not self.verifying:
            if self._pending is not None:
                raise OrderError(
                    "tell the outcome of the pending grasp before verifying"
                )
            rec = {"type": "verify", "rho_min": float(rho_min), "delta": float(delta)}
            self._apply(self.store.append(rec), replay=False)
        return self.verification_state()

    def verification_state(self) -> dict | None:
        """The run's verification: threshold, phase, its attempts and successes,
        its level δ_j, whether it is open, the last phase's verdict, the stop."""
        v = self.verification
        if v is None:
            return None
        return {
            "rho_min": v.rho,
            "delta": v.delta,
            "phase": v.phase,
            "open": v.active,
            "attempts": v.attempts,
            "successes": v.successes,
            "level": v.level,
            "verdict": self._verdict,
            "stopped": self.stopped,
        }

    def bound(self, rho_min: float | None = None) -> dict:
        """The paper's Dirichlet lower bound p̂_ℓ at the current step, over all
        candidates (and over attempted grasps only), and whether p̂_ℓ ≥ ρ_min
        (``stop``); beside it our bound (``p_lower_ours``, NaN for a method without
        per-grasp counts) and whether it is ≥ ρ_min (``stop_ours``)."""
        if rho_min is not None and (
            isinstance(rho_min, bool)
            or not isinstance(rho_min, (int, float))
            or not 0.0 <= rho_min <= 1.0
        ):
            raise InputError(f"rho_min must be a number in [0, 1], got {rho_min!r}")
        if not self.observed.any():
            lo = lo_att = 0.0
        else:
            lo, lo_att = self.loop.bound(self.counts, self.observed, self.step)
        out = {"step": self.step, "p_lower": lo, "p_lower_attempted": lo_att}
        out["p_lower_ours"] = self._bound_ours()
        if rho_min is not None:
            out["rho_min"] = float(rho_min)
            out["stop"] = bool(lo >= rho_min)
            out["stop_ours"] = bool(out["p_lower_ours"] >= rho_min)
        return out

    def _bound_ours(self) -> float:
        if not self.observed.any():
            return 0.0
        return self.loop.bound_ours(self.counts, self.observed, self.step)

    def status(self) -> dict:
        """Counters: step, successes, poses, the current pose, drop counts."""
        n = len(self.grasps)
        return {
            "method": self.method,
            "step": self.step,
            "successes": self.successes,
            "poses": n,
            "pose": self.pose,
            "counts": self.counts[:n].tolist(),
            "recommendation": self.loop.recommendation()[:n].tolist(),
            "verification": self.verification_state(),
        }

    def recommended(self, s: int) -> dict | None:
        """The recommended grasp of pose s (pose frame), or None."""
        g = int(self.loop.recommendation()[s])
        if g < 0:
            return None
        a = self.grasps[s]
        return {
            "grasp": g,
            "center": np.asarray(a["center"][g]),
            "axis": np.asarray(a["axis"][g]),
        }


def _pad(x: np.ndarray, K: int) -> np.ndarray:
    x = np.asarray(x, np.float32)
    out = np.zeros((K,) + x.shape[1:], np.float32)
    out[: len(x)] = x[:K]
    return out
