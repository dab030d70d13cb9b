"""A simulated robot: an overhead depth camera and a parallel-jaw gripper over
one object, with the physics of :mod:`precompute.grasps`.

The object rests in a stable pose at a random position (uniform in a square of
``±PLACE_RANGE`` about the table origin) and yaw (uniform). :meth:`SimRobot.render`
casts one ray per pixel with Embree (:mod:`precompute.raycast`) and adds Gaussian
depth noise (σ = ``NOISE``) and a fraction ``DROPOUT`` of missing pixels (NaN).
:meth:`SimRobot.execute` maps the asked grasp (table frame) into the object's pose
frame, perturbs it as the ground truth does (one draw of
:func:`precompute.grasps.perturbations`: translation, yaw, friction) and runs
:func:`precompute.grasps.execute` and force closure: success has probability p
of the grasp. After a success the object is dropped (next pose ~ λ), after a
failure it topples (next pose ~ the topple row), as in the batched engine; the
object is then placed anew.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

import precompute
from legs_jax.online.camera import Intrinsics, default_camera_pose
from legs_jax.online.recognition import yaw_matrix
from precompute import grasps as G
from precompute import poses as _poses
from precompute.catalog import data_dir
from precompute.errors import PrecomputeError
from precompute.mesh import _MESH_SUFFIXES, file_sha256, load_mesh
from precompute.raycast import RayCaster

__all__ = ["DEFAULT_INTRINSICS", "NOISE", "DROPOUT", "World", "SimRobot"]

DEFAULT_INTRINSICS = Intrinsics(
    fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480
)
NOISE = 0.001  # m, depth noise σ
DROPOUT = 0.005  # fraction of pixels without a reading
PLACE_RANGE = 0.05  # m


@dataclasses.dataclass(frozen=True, eq=False)
class World:
    """One object's stable poses: the mesh (metres, mesh frame), the transforms
    mesh → pose frame [P, 4, 4], landing λ [P] and topple [P, P]."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    transforms: np.ndarray
    landing: np.ndarray
    topple: np.ndarray

    @property
    def num_poses(self) -> int:
        return len(self.landing)

    @classmethod
    def from_mesh(cls, name: str) -> World:
        """Poses of catalogue object ``name`` computed from its mesh."""
        info = precompute.catalog.lookup(name)
        return cls.from_mesh_file(info.mesh_path, info.units, info.fit, name=name)

    @classmethod
    def from_mesh_file(
        cls, path, units: str, fit: str = "none", name: str | None = None
    ) -> World:
        """Poses of the mesh file at ``path`` (``units``, size rule ``fit`` as
        ``precompute --mesh`` takes them) computed from the mesh; named after the
        file unless ``name`` is given."""
        from pathlib import Path

        mesh = load_mesh(path, units, fit)
        hull = _poses.hull_model(mesh.vertices, mesh.faces, mesh.center_mass)
        sp = _poses.stable_poses(hull, mesh.vertices, mesh.faces)
        topple = _poses.topple_matrix(hull, sp)
        topple = topple / topple.sum(axis=1, keepdims=True)
        return cls(
            name or Path(path).stem,
            mesh.vertices,
            mesh.faces,
            sp.transforms,
            sp.landing,
            topple,
        )

    @classmethod
    def from_problem(cls, problem, mesh_path=None, problem_path=None) -> World:
        """The poses of a problem file and its object's mesh: ``mesh_path``, else
        the catalogue's mesh of that name, else the file the problem was built
        from (see :func:`_find_mesh`); the mesh must be the one the problem was
        built from (its SHA-256, when the problem records it)."""
        from pathlib import Path

        meta = problem.meta
        units, fit = meta.get("units", "m"), meta.get("fit", "none")
        scale = float(meta.get("scale", 1.0))  # precompute --scale
        want = meta.get("mesh_sha256")
        if mesh_path is None:
            try:
                info = precompute.catalog.lookup(problem.name)
            except PrecomputeError:
                info = None
            if info is not None and (
                want is None or file_sha256(info.mesh_path) == want
            ):
                mesh_path, units, fit = info.mesh_path, info.units, info.fit
                scale = 1.0
            else:  # a user's own mesh (perhaps named like a catalogue object)
                mesh_path = _find_mesh(problem, problem_path)
        mesh = load_mesh(mesh_path, units, fit, scale)
        if want is not None and mesh.sha256 != want:
            raise PrecomputeError(
                f"{Path(mesh_path)} is not the mesh the problem of {problem.name} "
                "was built from (its SHA-256 differs)"
            )
        keep = np.flatnonzero(problem.pose_valid)
        return cls(
            problem.name,
            mesh.vertices,
            mesh.faces,
            problem.pose_transform[keep].astype(np.float64),
            problem.landing[keep].astype(np.float64),
            problem.topple[np.ix_(keep, keep)].astype(np.float64),
        )

    @functools.lru_cache(maxsize=64)  # noqa: B019 - one world per run
    def posed(self, s: int) -> tuple[RayCaster, G.HeightMap]:
        """The Embree scene and height map of the mesh in pose s (pose frame)."""
        tf = self.transforms[s]
        v = self.vertices @ tf[:3, :3].T + tf[:3, 3]
        caster = RayCaster(v, self.faces)
        return caster, G.height_map(caster)

    @functools.lru_cache(maxsize=64)  # noqa: B019 - one world per run
    def bounds(self, s: int) -> tuple[np.ndarray, np.ndarray]:
        """(lowest, highest) corner of the mesh's box in pose s (pose frame)."""
        tf = self.transforms[s]
        v = self.vertices @ tf[:3, :3].T + tf[:3, 3]
        return v.min(0), v.max(0)


# how deep below each folder _find_mesh looks for a mesh by its name, and how
# many entries it reads at most (a large tree is not searched through)
_SEARCH_DEPTH = 2
_SEARCH_ENTRIES = 20_000


def _find_mesh(problem, problem_path=None):
    """The mesh file a problem file of the user's own (``precompute --mesh``) was
    built from, by what its meta records: each recorded path of the mesh
    (``mesh_file`` and any other ``mesh_*`` entry naming a mesh file), absolute
    or relative to the problem file's folder, to the repository, to the folder
    ``precompute --mesh`` ran from (two above the problem file) or to the current
    folder; else a file of the recorded name in or up to two folders below those
    folders. A candidate whose SHA-256 differs from the recorded one is passed
    over while another matches."""
    from pathlib import Path

    meta = problem.meta
    recorded = [meta["mesh_file"]] if isinstance(meta.get("mesh_file"), str) else []
    recorded += [
        v
        for k, v in sorted(meta.items())
        if k.startswith("mesh")
        and k != "mesh_file"
        and isinstance(v, str)
        and Path(v).suffix.lower() in _MESH_SUFFIXES
    ]
    bases, walk = [], [Path.cwd()]  # walk: the folders searched below
    if problem_path is not None:
        folder = Path(problem_path).resolve().parent
        bases += [folder, folder.parent.parent]
        walk.insert(0, folder.parent.parent)
    bases += [data_dir().resolve().parent, Path.cwd()]
    want = meta.get("mesh_sha256")

    def candidates():
        for rec in recorded:
            path = Path(rec).expanduser()
            if path.is_absolute():
                yield path
            else:
                yield from (base / path for base in bases)
        names = {Path(rec).name for rec in recorded}
        yield from (base / name for base in bases for name in names)
        for base in walk:
            yield from _below(base, names)

    seen, first = set(), None
    for cand in candidates():
        key = str(cand.resolve()) if cand.exists() else None
        if key is None or key in seen or not cand.is_file():
            continue
        seen.add(key)
        if want is None or file_sha256(cand) == want:
            return cand
        first = first or cand
    if first is not None:
        return first  # the caller says its SHA-256 differs
    shown = recorded[0] if recorded else None
    raise PrecomputeError(
        f"cannot find the mesh of {problem.name!r} (recorded as {shown!r}; looked "
        "beside the problem file, where it was built and in the current folder): "
        "give it as --object MESH beside --problem"
    )


def _below(base, names):
    """Files named one of ``names`` in the folders below ``base`` (at most
    ``_SEARCH_DEPTH`` deep, hidden folders skipped)."""
    import os

    budget = _SEARCH_ENTRIES
    level = [base]
    for _ in range(_SEARCH_DEPTH):
        nxt = []
        for folder in level:
            try:
                entries = list(os.scandir(folder))
            except OSError:
                continue
            budget -= len(entries)
            if budget < 0:
                return
            for e in entries:
                if e.name.startswith(".") or not e.is_dir(follow_symlinks=False):
                    continue
                sub = folder / e.name
                for name in names:
                    if (sub / name).is_file():
                        yield sub / name
                nxt.append(sub)
        level = nxt


class SimRobot:
    """The simulated cell around one :class:`World`; all draws from ``rng``."""

    def __init__(
        self,
        world: World,
        rng: np.random.Generator,
        *,
        intrinsics: Intrinsics = DEFAULT_INTRINSICS,
        camera_pose: np.ndarray | None = None,
        noise: float = NOISE,
        dropout: float = DROPOUT,
    ):
        self.world = world
        self.rng = rng
        self.intrinsics = intrinsics
        self.camera_pose = default_camera_pose() if camera_pose is None else camera_pose
        self.noise = noise
        self.dropout = dropout
        self.pose = 0
        self.placement = np.eye(4)  # pose frame -> table frame
        self._rays = None

    def _draw(self, probs) -> int:
        p = np.asarray(probs, np.float64)
        return int(self.rng.choice(len(p), p=p / p.sum()))

    def place(self, pose: int | None = None) -> None:
        """Put the object in ``pose`` (default: drawn from λ) at a random place."""
        self.pose = self._draw(self.world.landing) if pose is None else int(pose)
        tf = np.eye(4)
        tf[:3, :3] = yaw_matrix(self.rng.uniform(0.0, 2 * np.pi))
        tf[:2, 3] = self.rng.uniform(-PLACE_RANGE, PLACE_RANGE, 2)
        self.placement = tf

    def render(self) -> np.ndarray:
        """[H, W] noisy depth image (metres, NaN: no reading) of the object."""
        intr = self.intrinsics
        if self._rays is None:
            self._rays = intr.rays().reshape(-1, 3)
        caster, _ = self.world.posed(self.pose)
        # into the pose frame: camera -> table -> pose
        cam_to_pose = np.linalg.inv(self.placement) @ self.camera_pose
        R, t = cam_to_pose[:3, :3], cam_to_pose[:3, 3]
        # only the rays through the object's box can hit it: the others see the
        # table (the same image as casting every ray)
        cast = self._box_pixels(np.linalg.inv(cam_to_pose))
        hit = np.full(len(self._rays), np.inf)
        if len(cast):
            dirs = self._rays[cast] @ R.T
            hit[cast] = caster.cast_raw(np.broadcast_to(t, dirs.shape), dirs)[0]
        table = -t[2] / (self._rays @ R[2])  # the plane z = 0 (the table)
        depth = np.where(np.isfinite(hit) & (hit < table), hit, table)
        depth = depth.reshape(intr.height, intr.width)
        depth = depth + self.rng.normal(0.0, self.noise, depth.shape)
        depth[self.rng.random(depth.shape) < self.dropout] = np.nan
        return depth

    def _box_pixels(self, pose_to_cam: np.ndarray) -> np.ndarray:
        """Flat indices of the pixels whose rays may hit the object: the image
        rectangle around its bounding box's corners (a pixel wider), or every
        pixel when a corner is not in front of the camera."""
        intr = self.intrinsics
        W, H = intr.width, intr.height
        lo, hi = self.world.bounds(self.pose)
        corners = np.array(
            [
                [x, y, z]
                for x in (lo[0], hi[0])
                for y in (lo[1], hi[1])
                for z in (lo[2], hi[2])
            ]
        )
        cam = corners @ pose_to_cam[:3, :3].T + pose_to_cam[:3, 3]
        if np.any(cam[:, 2] <= 1e-6):
            return np.arange(W * H)
        uv = intr.project(cam)
        u0, v0 = np.maximum(np.floor(uv.min(0)).astype(int) - 1, 0)
        u1 = min(int(np.ceil(uv[:, 0].max())) + 1, W - 1)
        v1 = min(int(np.ceil(uv[:, 1].max())) + 1, H - 1)
        if u0 > u1 or v0 > v1:
            return np.zeros(0, np.int64)
        vv, uu = np.mgrid[v0 : v1 + 1, u0 : u1 + 1]
        return (vv * W + uu).ravel()

    def to_pose_frame(self, center: np.ndarray, axis: np.ndarray):
        """A grasp in the table frame -> the object's pose frame."""
        inv = np.linalg.inv(self.placement)
        return inv[:3, :3] @ center + inv[:3, 3], inv[:3, :3] @ axis

    def execute(self, center_table, axis_table, *, pose_frame: bool = False) -> bool:
        """One perturbed execution of the grasp (table frame, or the pose frame
        when ``pose_frame``); the object then drops or topples and is placed anew
        in its next pose."""
        c = np.asarray(center_table, np.float64)
        a = np.asarray(axis_table, np.float64)
        if not pose_frame:
            c, a = self.to_pose_frame(c, a)
        ok = self.success(c, a)
        self.transition(ok)
        return ok

    def success(self, center_pose, axis_pose, samples: int = 1) -> bool | float:
        """Perturbed executions of a pose-frame grasp in the current pose: one
        outcome (samples=1) or the fraction of ``samples`` that succeed."""
        caster, hmap = self.world.posed(self.pose)
        dxy, dyaw, mu = G.perturbations(self.rng, 1, samples)
        p = G.robustness(
            caster,
            hmap,
            np.asarray(center_pose)[None],
            np.asarray(axis_pose)[None],
            dxy,
            dyaw,
            mu,
        )
        return bool(p[0] > 0.5) if samples == 1 else float(p[0])

    def transition(self, success: bool) -> None:
        row = self.world.landing if success else self.world.topple[self.pose]
        self.place(self._draw(row))
