"""Mesh -> problem file and the cache of built problems.

Pipeline of one object: load and repair the mesh (:mod:`.mesh`), stable poses and
landing probabilities, topple matrix (:mod:`.poses`), then per pose: an Embree scene
of the posed mesh and its height map, T reservoirs of K grasps (:mod:`.grasps`), the
ground truth p of every grasp from S perturbed executions (all trials of a pose in a
few large Embree calls), and the prior q: learned (:mod:`.learned`, a network that
sees the pose's depth image and the grasps, never p) or synthetic (:mod:`.prior`,
made from p); ``BuildParams.prior`` chooses, defaulting to learned when its weights
are shipped (``precompute/prior_weights/weights.npz``) and to synthetic until then.

Randomness: every stream is a NumPy ``Generator`` seeded by
``SeedSequence([seed, object_key, pose, trial, stream])``, with ``object_key`` a
hash of the object's name and streams 1 (grasp sampling), 2 (perturbations),
3 (synthetic prior noise) and 4 (the learned prior's sensor noise). Nothing
depends on the order of work or the number of processes, and the same inputs give
byte-identical files.

Up-to-date check: a problem file records ``meta["build_hash"]``, a SHA-256 of the
mesh file's bytes, its units and size rule, every build parameter, the gripper and
prior constants (for the learned prior: the weights' SHA-256, camera and noise) and
``CODE_VERSION``; a file whose hash matches is not rebuilt. ``CODE_VERSION`` is
bumped whenever a change alters the output. A file that differs only in its prior's
constants (its hash matches when computed with the prior it records) keeps its
poses, grasps and ground truth: only q is recomputed (:func:`reprior`),
byte-identical to a full build with the new constants.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from legs_jax.core import problem as problem_mod  # the one reader of the format
from legs_jax.core.problem import Problem, load, save, unlearnable_poses

from . import catalog as _catalog
from . import grasps as G
from . import learned as _learned
from . import poses as _poses
from . import prior as _prior
from .errors import PrecomputeError
from .mesh import file_sha256, load_mesh
from .raycast import RayCaster, face_pad_normals
from .urdf import urdf_geometry

__all__ = [
    "CODE_VERSION",
    "BuildParams",
    "build_problem",
    "build_hash",
    "object_key",
    "reprior",
    "synthetic_prior",
    "problem_path",
    "read_meta",
    "is_up_to_date",
]

CODE_VERSION = "2"

STREAM_GRASPS = 1
STREAM_PERTURB = 2
STREAM_PRIOR = 3
STREAM_DEPTH = 4


@dataclasses.dataclass(frozen=True)
class BuildParams:
    """What a build depends on besides the mesh."""

    trials: int = 10  # T reservoirs
    grasps: int = 2000  # K grasps per reservoir and pose
    samples: int = G.SAMPLES  # perturbed executions per grasp
    seed: int = 0
    landing_threshold: float = _poses.LANDING_THRESHOLD
    # "learned" or "synthetic"; the default is learned once weights are shipped
    prior: str = dataclasses.field(default_factory=_learned.default_prior)
    # weights of the learned prior other than the shipped ones (None: shipped);
    # in the hash through the prior's constants (their SHA-256), not as a path
    prior_weights: str | None = None

    def check(self) -> BuildParams:
        if self.prior not in _learned.PRIORS:
            raise PrecomputeError(
                f"unknown prior '{self.prior}' (choose one of "
                f"{', '.join(_learned.PRIORS)})"
            )
        if self.prior_weights is not None and self.prior != "learned":
            raise PrecomputeError(
                "--prior-weights names weights of the learned prior: it cannot go "
                f"with --prior {self.prior}"
            )
        if self.prior == "learned":
            # a clear error when the weights are missing
            _learned.prior_params(self.prior_weights)
        if self.trials < 1:
            raise PrecomputeError(f"--trials must be at least 1, got {self.trials}")
        if self.grasps < 1:
            raise PrecomputeError(f"--grasps must be at least 1, got {self.grasps}")
        if self.samples < 1:
            raise PrecomputeError(f"--samples must be at least 1, got {self.samples}")
        if self.seed < 0:
            raise PrecomputeError(f"--seed must be non-negative, got {self.seed}")
        if not 0.0 <= self.landing_threshold < 1.0:
            raise PrecomputeError(
                f"landing threshold must lie in [0, 1), got {self.landing_threshold}"
            )
        return self


def object_key(name: str) -> int:
    """Stable integer of an object name (seeding)."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little") % (
        2**31
    )


def build_hash(
    mesh_sha256: str,
    units: str,
    name: str,
    params: BuildParams,
    fit: str = "none",
    prior: dict | None = None,
    scale: float = 1.0,
) -> str:
    """The hash of everything a build depends on; ``prior``: the prior's constants
    (default: the current ones of the prior ``params.prior``); ``scale``: the
    factor after the units (in the hash only when not 1, so that the hashes of
    builds without it stay as they were)."""
    hashed = dataclasses.asdict(params)
    del hashed["prior"]  # in "prior" below (synthetic builds keep their old hash)
    del hashed["prior_weights"]  # its SHA-256 is in "prior" below
    blob = json.dumps(
        {
            "mesh_sha256": mesh_sha256,
            "units": units,
            "fit": fit,
            "name": name,
            "params": hashed,
            "gripper": G.gripper_params(),
            "prior": prior if prior is not None else prior_params(params),
            "tilt": [_poses.TILT_SIGMA_DEG, _poses.TILT_ANGLES, _poses.TILT_AZIMUTHS],
            "code_version": CODE_VERSION,
            **({"scale": float(scale)} if float(scale) != 1.0 else {}),
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def prior_params(params: BuildParams) -> dict:
    """The constants of the chosen prior (meta and build hash)."""
    if params.prior == "learned":
        return _learned.prior_params(params.prior_weights)
    return _prior.prior_params()


def _rng(params: BuildParams, name: str, pose: int, trial: int, stream: int):
    ss = np.random.SeedSequence([params.seed, object_key(name), pose, trial, stream])
    return np.random.Generator(np.random.PCG64(ss))


def build_problem(
    mesh_path: str | Path,
    *,
    units: str,
    name: str,
    fit: str = "none",
    set_name: str = "custom",
    params: BuildParams | None = None,
    scale: float = 1.0,
    problem_file: str | Path | None = None,
    on_poses: Callable[[int], None] | None = None,
    on_pose_done: Callable[[], None] | None = None,
):
    """Build the :class:`legs_jax.core.problem.Problem` of one mesh (``scale``:
    the factor after ``units``; ``problem_file``: where the problem will be saved,
    so that a mesh of the user's own is recorded relative to it).

    ``on_poses(P)`` is called once the number of poses is known and
    ``on_pose_done()`` after each pose (progress bars).
    """
    params = (params or BuildParams()).check()
    mesh = load_mesh(mesh_path, units, fit, scale)
    com = mesh.center_mass
    try:
        hull = _poses.hull_model(mesh.vertices, mesh.faces, com)
    except ValueError as e:
        raise PrecomputeError(f"{mesh.path}: degenerate: {e}") from None
    sp = _poses.stable_poses(
        hull, mesh.vertices, mesh.faces, threshold=params.landing_threshold
    )
    topple = _poses.topple_matrix(hull, sp)
    P, T, K, S = len(sp.landing), params.trials, params.grasps, params.samples
    if on_poses is not None:
        on_poses(P)

    rob = np.zeros((T, P, K), np.float32)
    learned_prior = np.zeros((T, P, K), np.float32)
    valid = np.zeros((T, P, K), bool)
    center = np.zeros((T, P, K, 3), np.float32)
    axis = np.zeros((T, P, K, 3), np.float32)
    width = np.zeros((T, P, K), np.float32)
    height = np.zeros((T, P, K), np.float32)
    pose_info = []
    # pad normals of the unposed mesh, turned with each pose (one KD-tree per mesh)
    pad = face_pad_normals(mesh.vertices, mesh.faces, G.PAD_RADIUS)
    for s in range(P):
        tf = sp.transforms[s]
        posed = _rotate(mesh.vertices, tf[:3, :3]) + tf[:3, 3]
        caster = RayCaster(
            posed, mesh.faces, pad_normals={G.PAD_RADIUS: _rotate(pad, tf[:3, :3])}
        )
        hmap = G.height_map(caster)
        res = [
            G.sample_reservoir(caster, hmap, K, _rng(params, name, s, t, STREAM_GRASPS))
            for t in range(T)
        ]
        # every trial's perturbations from its own stream, one block per slot
        dxy, dyaw, mu, c_all, a_all, where = [], [], [], [], [], []
        for t, r in enumerate(res):
            d1, d2, d3 = G.perturbations(_rng(params, name, s, t, STREAM_PERTURB), K, S)
            v = r.valid
            dxy.append(d1[v])
            dyaw.append(d2[v])
            mu.append(d3[v])
            c_all.append(r.center[v])
            a_all.append(r.axis[v])
            where.append(np.flatnonzero(v))
        p_flat = G.robustness(
            caster,
            hmap,
            np.concatenate(c_all),
            np.concatenate(a_all),
            np.concatenate(dxy),
            np.concatenate(dyaw),
            np.concatenate(mu),
        )
        if params.prior == "learned":
            learned_q = _learned.score_reservoirs(
                caster,
                res,
                [_rng(params, name, s, t, STREAM_DEPTH) for t in range(T)],
                params.prior_weights,
            )
        offset = 0
        for t, r in enumerate(res):
            idx = where[t]
            p = p_flat[offset : offset + len(idx)]
            offset += len(idx)
            rob[t, s, idx] = p
            valid[t, s] = r.valid
            center[t, s] = r.center
            axis[t, s] = r.axis
            width[t, s] = r.width
            height[t, s] = r.center[:, 2]
            if params.prior == "learned":
                learned_prior[t, s] = learned_q[t]
        pose_info.append(
            {
                "landing": round(float(sp.landing[s]), 6),
                "merged_facets": len(sp.members[s]),
                "valid_grasps": [int(r.valid.sum()) for r in res],
                "candidates": [int(r.candidates) for r in res],
                "com_height": round(float(tf[2, 3]), 6),
            }
        )
        if on_pose_done is not None:
            on_pose_done()

    if params.prior == "learned":
        prior = learned_prior
    else:
        prior = synthetic_prior(params, name, rob, valid)
    landing = sp.landing / sp.landing.sum()
    topple = topple / topple.sum(axis=1, keepdims=True)
    meta = {
        "name": name,
        "set": set_name,
        **_mesh_meta(mesh, set_name, scale, problem_file),
        "mesh_sha256": mesh.sha256,
        "units": units,
        "mesh_scale": mesh.scale,
        "fit": fit,
        "pose_transform_note": (
            "rigid transforms of the mesh after scaling by mesh_scale (file units "
            "to metres, the size rule `fit` included); "
            "pose frame: table z=0, z up, centre of mass above the origin"
        ),
        "repairs": list(mesh.repairs),
        "params": _meta_params(params),
        "gripper": G.gripper_params(),
        **_prior_meta(params),
        "topple_tilts": {
            "sigma_deg": _poses.TILT_SIGMA_DEG,
            "angles": _poses.TILT_ANGLES,
            "azimuths": _poses.TILT_AZIMUTHS,
        },
        "stable_facets": sp.num_candidates,
        "dropped_landing_mass": round(sp.dropped_mass, 6),
        "poses": pose_info,
        "code_version": CODE_VERSION,
        "build_hash": build_hash(
            mesh.source_sha256, units, name, params, fit, scale=scale
        ),
    }
    problem = Problem(
        name=name,
        landing=landing.astype(np.float32),
        topple=topple.astype(np.float32),
        robustness=rob,
        prior=prior,
        valid=valid,
        grasp_center=center,
        grasp_axis=axis,
        grasp_width=width,
        grasp_height=height,
        pose_transform=sp.transforms.astype(np.float32),
        pose_valid=np.ones(P, bool),
        meta=meta,
    )
    problem = problem.validate()
    # the poses no method can learn in: recorded, and said by the build
    flags = unlearnable_poses(problem)
    return dataclasses.replace(problem, meta={**meta, "unlearnable": flags})


def synthetic_prior(
    params: BuildParams, name: str, rob: np.ndarray, valid: np.ndarray
) -> np.ndarray:
    """[T, P, K] float32 synthetic q (:mod:`.prior`, current constants) of every
    reservoir slot, 0 on padding; each (trial, pose) from its own seeded stream."""
    T, P, K = rob.shape
    prior = np.zeros((T, P, K), np.float32)
    for t in range(T):
        for s in range(P):
            eps = _prior.prior_noise(_rng(params, name, s, t, STREAM_PRIOR), K)
            q = _prior.prior_from_noise(rob[t, s].astype(np.float64), eps)
            prior[t, s] = np.where(valid[t, s], q, 0.0)
    return prior


def _prior_meta(params: BuildParams) -> dict:
    """The meta entries that name the prior of a build."""
    constants = prior_params(params)
    if params.prior == "learned":
        label = (
            "learned GQ-CNN-style network (weights sha256 "
            f"{constants['weights_sha256'][:12]})"
        )
        return {
            "prior_kind": "learned",
            "prior": constants,
            "prior_label": label,
            "prior_weights": _learned.weights_meta(params.prior_weights),
        }
    # a synthetic build's meta is as it was before the learned prior existed (no
    # prior_kind: readers take its absence as synthetic), so its files stay
    # byte-identical and results pinned to them stay current
    label = "synthetic GQ-CNN stand-in (not a learned network)"
    return {"prior": constants, "prior_label": label}


def _meta_params(params: BuildParams) -> dict:
    """The build parameters as meta records them (the prior field only for a
    learned build, for the same reason as :func:`_prior_meta`)."""
    d = dataclasses.asdict(params)
    del d["prior_weights"]  # in meta["prior_weights"] (learned builds)
    if params.prior != "learned":
        del d["prior"]
    return d


@dataclasses.dataclass(frozen=True)
class _Slots:
    """A reservoir as a problem file stores it (what the learned prior scores)."""

    valid: np.ndarray  # [K]
    center: np.ndarray  # [K, 3] float32
    axis: np.ndarray  # [K, 3] float32


def _learned_prior_of(info, params: BuildParams, pb) -> np.ndarray | None:
    """[T, P, K] learned q of the grasps of problem ``pb`` (catalogue object
    ``info``), as a full build computes it: the mesh posed again (the same
    deterministic poses, checked against the file's), each pose rendered, the
    stored grasps scored. None when the poses do not match (a full build then)."""
    try:
        mesh = load_mesh(info.mesh_path, info.units, info.fit)
        hull = _poses.hull_model(mesh.vertices, mesh.faces, mesh.center_mass)
        sp = _poses.stable_poses(
            hull, mesh.vertices, mesh.faces, threshold=params.landing_threshold
        )
    except (PrecomputeError, ValueError):
        return None
    tfs = sp.transforms
    if tfs.shape != pb.pose_transform.shape or not np.array_equal(
        tfs.astype(np.float32), pb.pose_transform
    ):
        return None
    T, P, K = pb.prior.shape
    q = np.zeros((T, P, K), np.float32)
    for s in range(P):
        tf = tfs[s]
        caster = RayCaster(_rotate(mesh.vertices, tf[:3, :3]) + tf[:3, 3], mesh.faces)
        slots = [
            _Slots(pb.valid[t, s], pb.grasp_center[t, s], pb.grasp_axis[t, s])
            for t in range(T)
        ]
        rngs = [_rng(params, info.name, s, t, STREAM_DEPTH) for t in range(T)]
        q[:, s] = _learned.score_reservoirs(caster, slots, rngs, params.prior_weights)
    return q


def reprior(path: Path, info, params: BuildParams) -> bool:
    """Recompute the prior of the problem file at ``path`` (catalogue object
    ``info``) with the current constants of the prior ``params.prior``, when the
    file is current in everything else (whichever prior it carries); True when it
    was rewritten (False: it needs a full build). The learned prior needs the
    poses again (seconds an object) and then only renders and scores."""
    import dataclasses as _dc

    meta = read_meta(path)
    if meta is None or not isinstance(meta.get("prior"), dict):
        return False
    mesh_sha = file_sha256(info.mesh_path)
    old = build_hash(mesh_sha, info.units, info.name, params, info.fit, meta["prior"])
    if meta.get("build_hash") != old:
        return False
    pb = load(path)
    if params.prior == "learned":
        q = _learned_prior_of(info, params, pb)
        if q is None:
            return False
    else:
        q = synthetic_prior(params, info.name, pb.robustness, pb.valid)
    new_meta = dict(pb.meta)
    new_meta.update(_prior_meta(params))
    new_meta["params"] = _meta_params(params)
    if params.prior != "learned":
        new_meta.pop("prior_kind", None)
        new_meta.pop("prior_weights", None)
    new_meta["build_hash"] = build_hash(
        mesh_sha, info.units, info.name, params, info.fit
    )
    save(_dc.replace(pb, prior=q, meta=new_meta), path)
    return True


def _rotate(points: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """points [N, 3] @ rot.T, written out so that it rounds the same on every
    processor (a BLAS product picks its kernel, and its rounding, by CPU)."""
    x, y, z = points[:, 0:1], points[:, 1:2], points[:, 2:3]
    return x * rot[:, 0] + y * rot[:, 1] + z * rot[:, 2]


def _mesh_meta(mesh, set_name: str, scale: float, problem_file) -> dict:
    """Where the mesh of a problem is (``mesh_file``) and how it was read. A
    catalogue object, or a mesh of the repository's data: its path in the
    repository. A mesh of the user's own (set "custom"): its path
    relative to the problem file's folder (``mesh_file``: later commands find it
    from the problem file, wherever both are moved together), its absolute path
    (``mesh_file_abs``), the factor after the units (``scale``) and, for a URDF,
    the mesh files and scales it names (``urdf``)."""
    absolute = Path(mesh.path).resolve()
    if set_name != "custom" or _catalog.data_dir().resolve() in absolute.parents:
        # a catalogue object, or a mesh of the repository's data: as before
        return {"mesh_file": _display_path(mesh.path)}
    if problem_file is not None:
        folder = Path(problem_file).resolve().parent
        rel = os.path.relpath(absolute, folder)
    else:
        rel = absolute.name
    out = {
        "mesh_file": rel,
        "mesh_file_abs": str(absolute),
        "scale": float(scale),
    }
    if absolute.suffix.lower() == ".urdf":
        out["urdf"] = [
            {
                "kind": g["kind"],
                "source": g["source"],
                **(
                    {
                        "file": os.path.relpath(
                            Path(g["file"]).resolve(), absolute.parent
                        ),
                        "scale": [float(x) for x in g["scale"]],
                    }
                    if g["kind"] == "mesh"
                    else {"size": [float(x) for x in g["size"]]}
                ),
            }
            for g in urdf_geometry(absolute)
        ]
    return out


def _display_path(path: Path) -> str:
    """The mesh path relative to the repository when inside it (no machine paths)."""
    try:
        return str(path.resolve().relative_to(_catalog.data_dir().resolve().parent))
    except ValueError:
        return path.name


# ----------------------------------------------------------------------- the cache


def problems_dir(data_dir: Path | None = None, prior: str | None = None) -> Path:
    """Where problem files are written: ``<data>/problems`` when writable, else the
    user cache (``$XDG_CACHE_HOME/legs_jax/problems``). Files with a prior other
    than the default one (:func:`.learned.default_prior`) live apart, in its
    ``prior-<kind>`` subfolder, so that both kinds can be kept side by side."""
    base = Path(data_dir) if data_dir is not None else _catalog.data_dir()
    out = base / "problems"
    if not _writable(out):
        cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
        out = cache / "legs_jax" / "problems"
    if prior is not None and prior != _learned.default_prior():
        out = out / f"prior-{prior}"
    return out


def _writable(folder: Path) -> bool:
    probe = folder
    while not probe.exists():
        if probe.parent == probe:
            return False
        probe = probe.parent
    return os.access(probe, os.W_OK)


def problem_path(info, out: Path) -> Path:
    return Path(out) / info.set / f"{info.name}.npz"


def read_meta(path: Path) -> dict | None:
    """The meta dict of a problem file without loading its arrays (None if
    unreadable)."""
    try:
        return problem_mod.peek(path)["meta"]
    except Exception:  # noqa: BLE001 - any unreadable file is simply out of date
        return None


def is_up_to_date(path: Path, expected_hash: str) -> bool:
    if not Path(path).is_file():
        return False
    meta = read_meta(path)
    return meta is not None and meta.get("build_hash") == expected_hash


def expected_hash(info, params: BuildParams) -> str:
    return build_hash(
        file_sha256(info.mesh_path), info.units, info.name, params, info.fit
    )


def out_of_date(
    names: Sequence[str],
    *,
    data_dir: Path | None = None,
    params: BuildParams | None = None,
) -> list:
    """The catalogue objects among ``names`` (object or set names) whose problem
    file is missing or out of date: what :func:`precompute.runner.ensure` would
    build."""
    root = Path(data_dir) if data_dir is not None else None
    params = (params or BuildParams()).check()
    out = problems_dir(root, params.prior)
    return [
        i
        for i in _catalog.resolve(list(names), root=root)
        if not is_up_to_date(problem_path(i, out), expected_hash(i, params))
    ]
