"""Stable-pose recognition from depth images (the paper's Section 6).

Depth image → table-frame point cloud with the intrinsics and the camera pose →
the object's points (more than ``MIN_HEIGHT`` above the table) on a ``VOXEL``
grid → demeaned in x and y (the table fixes z, so heights stay comparable). The
cloud is compared with every cached pose's cloud over 3600 yaws (0.1°) about the
vertical (the optical axis of an overhead camera) by the observed → cached half
of the chamfer distance, searched coarse to fine: all 360 whole degrees, then the
0.1° yaws within ±1° of the best ``REFINE`` coarse ones (a 1° step moves a point
5 cm from the centre by 0.9 mm, under the tolerance). The search reads the
distances from a :class:`DistanceGrid` of the cached pose (2 mm lattice, built
once, the first time the pose is a candidate: nearest node for the coarse yaws,
trilinear for the fine ones) instead of searching a KD-tree for each point. The
best yaw is refined by trimmed ICP (rotation about the vertical and a
translation; the 80 % closest pairs) on ``ICP_POINTS`` of the observed points;
the fractions below use every point and exact nearest neighbours. The clouds
show the same pose when at least ``MATCH_FRACTION`` = 80 % of the observed points
lie within ``TOLERANCE`` of the cached cloud and 80 % of the cached points within
it of the observed cloud (both ways, so that a cloud that covers only part of
another is no match). Otherwise the cloud is cached as a new
pose.

The paper prints a tolerance of 0.02 mm, far below the noise of any depth sensor
(σ = 1 mm in the simulated camera). We use ``TOLERANCE`` = 2.5 mm: on simulated
views of the Dex-Net objects every view of a cached pose had at least 82 % of its
points within 2.5 mm (at 2 mm some fell under 80 %, which would create duplicate
poses), while most pairs of different poses stay under 80 %. Some poses of a few
objects differ by less than the sensor noise from above and cannot be told apart
(results/online/recognition.md).

Only the ``CANDIDATES`` = 4 cached poses nearest by a yaw-invariant descriptor (a
histogram of distance from the centroid's vertical × height) are aligned in full;
on those views the right pose was always first or second by descriptor, and it
keeps recognition time flat in the number of cached poses. They are aligned in
the descriptor's order and the first that matches is taken (``first_match``;
``first_match=False`` aligns all of them and takes the best fraction): a known
pose usually costs one alignment instead of four, a new pose still all four.

Exact nearest neighbours (ICP, the fractions) come from SciPy's ``cKDTree`` (one
tree per cached pose, kept in memory; one thread: the queries are small, and
threads cost more than they save on a busy machine).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from legs_jax.online.camera import Intrinsics
from legs_jax.online.errors import InputError

__all__ = [
    "MATCH_FRACTION",
    "MIN_HEIGHT",
    "MIN_POINTS",
    "TOLERANCE",
    "VOXEL",
    "Match",
    "PoseLibrary",
    "object_cloud",
]

TOLERANCE = 0.0025  # m
MATCH_FRACTION = 0.8
MIN_HEIGHT = 0.004  # m above the table: object points
VOXEL = 0.002  # m
MIN_POINTS = 30  # fewer object voxels: no object in view
SEARCH_POINTS = 256  # observed points scored at each of the coarse yaws
REFINE = 3
COARSE_STEP_DEG = 1.0
CANDIDATES = 4  # cached poses aligned in full (nearest by descriptor)
_DESC_BINS = 25  # 4 mm bins over 10 cm
ICP_ITERATIONS = 15
ICP_POINTS = 512  # observed points ICP iterates on (the fractions use all)
ICP_KEEP = 0.8
_CAP = 0.02  # distances are capped here in the chamfer score (outliers)
GRID = 0.002  # m, lattice spacing of a cached pose's distance grid
_DENSE = 3 * VOXEL  # a point with no other within this is a stray reading


def object_cloud(
    depth: np.ndarray, intr: Intrinsics, camera_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(points [N, 3] of the object on the voxel grid, table frame; mask [H, W] of
    the object's pixels). Raises :class:`InputError` when no object is in view.

    The height above the table is computed for every pixel, the full
    deprojection (:func:`legs_jax.online.camera.deproject`) only for the
    object's pixels."""
    ray = intr.rays()
    R, t = camera_pose[:3, :3], camera_pose[:3, 3]
    height = (ray * depth[..., None]) @ R[2] + t[2]
    mask = np.isfinite(height) & (height > MIN_HEIGHT)
    p = (ray[mask] * depth[mask][:, None]) @ R.T + t
    if len(p):
        p = voxel_down(p, VOXEL)
    if len(p) < MIN_POINTS:
        raise InputError(
            f"no object in view: {len(p)} voxels of {VOXEL * 1000:g} mm lie more "
            f"than {MIN_HEIGHT * 1000:g} mm above the table (at least {MIN_POINTS} "
            "needed)"
        )
    return p, mask


def voxel_down(p: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the mean) per occupied voxel, in the voxels' lexicographic
    order (x, then y, then z)."""
    idx = np.floor(p / voxel).astype(np.int64)
    idx -= idx.min(0)
    span = idx.max(0) + 1
    key = (idx[:, 0] * span[1] + idx[:, 1]) * span[2] + idx[:, 2]
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    n = len(counts)
    out = np.stack([np.bincount(inv, p[:, k], n) for k in range(3)], axis=1)
    return out / counts[:, None]


def yaw_matrix(a) -> np.ndarray:
    """[..., 3, 3] rotations by yaw a about z."""
    a = np.asarray(a, np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)],
        -2,
    )


@dataclasses.dataclass(frozen=True)
class Match:
    """Outcome of recognising one cloud."""

    pose: int | None  # cached pose index, None for a new pose
    transform: np.ndarray  # [4, 4] table frame -> pose frame of the match
    fraction: float  # min of the two within-tolerance fractions (0 with no cache)
    best_pose: int | None  # the closest cached pose even when it did not match
    candidates: int  # cached poses compared in full


class DistanceGrid:
    """The distance (capped at ``_CAP``) from the nodes of a lattice of ``GRID``
    spacing to a cloud, over the box of the cloud's dense points (stray readings
    left out) widened by ``_CAP``; ``_CAP`` outside it. A lookup costs a few
    array operations per point instead of a KD-tree search."""

    def __init__(self, tree: cKDTree, cloud: np.ndarray):
        d2, _ = tree.query(cloud, k=2)
        dense = cloud[d2[:, 1] <= _DENSE]
        if len(dense) == 0:
            dense = cloud
        lo = dense.min(0) - _CAP
        n = np.floor((dense.max(0) + _CAP - lo) / GRID).astype(np.int64) + 2
        axes = [lo[i] + GRID * np.arange(n[i]) for i in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        d, _ = tree.query(nodes, distance_upper_bound=_CAP)
        self.values = np.minimum(d, _CAP)  # [n0 * n1 * n2]
        self.lo = lo
        self.shape = n
        self.stride = np.array([n[1] * n[2], n[2], 1])

    def nearest(self, pts: np.ndarray) -> np.ndarray:
        """Capped distances of points [..., 3], read at the nearest node."""
        i = np.rint((pts - self.lo) / GRID).astype(np.int64)
        inside = np.all((i >= 0) & (i < self.shape), axis=-1)
        return np.where(inside, self.values[np.where(inside, i @ self.stride, 0)], _CAP)

    def __call__(self, pts: np.ndarray) -> np.ndarray:
        """Capped distances of points [..., 3], trilinear between nodes."""
        u = (pts - self.lo) / GRID
        i = np.floor(u)
        f = u - i
        i = i.astype(np.int64)
        inside = np.all((i >= 0) & (i < self.shape - 1), axis=-1)
        b = np.where(inside, i @ self.stride, 0)
        V, (sx, sy, _) = self.values, self.stride
        fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]

        def line(o):  # along z from node b + o
            return V[b + o] * (1.0 - fz) + V[b + o + 1] * fz

        y0 = line(0) * (1.0 - fy) + line(sy) * fy
        y1 = line(sx) * (1.0 - fy) + line(sx + sy) * fy
        return np.where(inside, y0 * (1.0 - fx) + y1 * fx, _CAP)


def _rotated(yaws: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """[A, N, 3]: ``sample`` [N, 3] rotated by each yaw [A] about z."""
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    x, y = sample[:, 0], sample[:, 1]
    z = np.broadcast_to(sample[:, 2], (len(yaws), len(sample)))
    return np.stack([c * x - s * y, s * x + c * y, z], axis=-1)


def _yaw3(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _planar_icp(src: np.ndarray, tree: cKDTree, dst: np.ndarray, R, t):
    """Trimmed ICP with a yaw rotation and a 3-D translation, from (R, t)."""
    k = max(int(np.ceil(ICP_KEEP * len(src))) - 1, 0)
    for _ in range(ICP_ITERATIONS):
        cur = src @ R.T + t
        d, j = tree.query(cur)
        keep = d <= np.partition(d, k)[k]
        a, b = src[keep], dst[j[keep]]
        ma, mb = a.mean(0), b.mean(0)
        A, B = a[:, :2] - ma[:2], b[:, :2] - mb[:2]
        yaw = np.arctan2(np.sum(A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0]), np.sum(A * B))
        R_new = _yaw3(yaw)
        t_new = mb - R_new @ ma
        done = np.abs(R_new - R).max() <= 1e-7 and np.abs(t_new - t).max() <= 1e-7
        R, t = R_new, t_new
        if done:
            break
    return R, t


def descriptor(cloud: np.ndarray) -> np.ndarray:
    """A yaw-invariant signature of a pose-frame cloud: the normalised 2-D
    histogram of (distance from the vertical through the centroid, height)."""
    r = np.hypot(cloud[:, 0], cloud[:, 1])
    h, _, _ = np.histogram2d(
        r, cloud[:, 2], bins=(_DESC_BINS, _DESC_BINS), range=((0, 0.1), (0, 0.1))
    )
    return (h / max(len(cloud), 1)).ravel()


@dataclasses.dataclass(frozen=True)
class Alignment:
    """The best alignment of an observed cloud onto one cached pose."""

    pose: int
    R: np.ndarray  # [3, 3] yaw
    t: np.ndarray  # [3]
    forward: np.ndarray  # [N] distance of each observed point to the cached cloud
    backward: np.ndarray  # [M] distance of each cached point to the observed cloud

    def fraction(self, tolerance: float) -> float:
        """The smaller of the two within-tolerance fractions."""
        return min(
            float(np.mean(self.forward < tolerance)),
            float(np.mean(self.backward < tolerance)),
        )


class PoseLibrary:
    """The cached clouds of the poses seen so far (pose frames: demeaned in x, y).

    Only the ``CANDIDATES`` cached poses nearest by :func:`descriptor` (a
    yaw-invariant histogram, cheap to compare) go through the yaw search and ICP.
    """

    def __init__(
        self,
        seed: int = 0,
        tolerance: float = TOLERANCE,
        match_fraction: float = MATCH_FRACTION,
        first_match: bool = True,
    ):
        self.clouds: list[np.ndarray] = []
        self._trees: list[cKDTree] = []
        self._desc: list[np.ndarray] = []
        self._grids: list[DistanceGrid | None] = []
        self._seed = seed
        self.tolerance = tolerance
        self.match_fraction = match_fraction
        self.first_match = first_match

    def __len__(self) -> int:
        return len(self.clouds)

    def add(self, cloud: np.ndarray) -> int:
        """Cache ``cloud`` (pose frame) as a new pose; its index."""
        c = np.asarray(cloud, np.float64)
        self.clouds.append(c)
        self._trees.append(cKDTree(c))
        self._desc.append(descriptor(c))
        self._grids.append(None)
        return len(self.clouds) - 1

    def _grid(self, j: int) -> DistanceGrid:
        """Pose j's distance grid, built when it is first a candidate."""
        if self._grids[j] is None:
            self._grids[j] = DistanceGrid(self._trees[j], self.clouds[j])
        return self._grids[j]

    def align(self, points: np.ndarray, stop_at: float | None = None):
        """(the demeaned cloud, its mean, the alignments onto the candidate cached
        poses, best first by the fraction at the library's tolerance).

        ``stop_at``: align the candidates in the descriptor's order and stop after
        the first whose fraction reaches it (it is then the only one returned)."""
        mean = points.mean(0)
        mean[2] = 0.0
        obs = points - mean
        if not self.clouds:
            return obs, mean, []
        rng = np.random.default_rng(self._seed)
        n = len(obs)
        sample = obs[rng.choice(n, min(n, SEARCH_POINTS), replace=False)]
        icp_src = obs[rng.choice(n, min(n, ICP_POINTS), replace=False)]
        obs_tree = cKDTree(obs)
        d_obs = descriptor(obs)
        dist = [float(np.abs(d_obs - d).sum()) for d in self._desc]
        cands = np.argsort(dist, kind="stable")[:CANDIDATES]
        coarse = np.deg2rad(np.arange(0.0, 360.0, COARSE_STEP_DEG))
        rs_coarse = _rotated(coarse, sample)
        step = np.deg2rad(np.arange(-10, 11) * 0.1 * COARSE_STEP_DEG)
        out = []
        for j in cands:
            tree, grid = self._trees[j], self._grid(j)
            sc = grid.nearest(rs_coarse).mean(axis=1)
            fine = (coarse[np.argsort(sc)[:REFINE], None] + step).ravel()
            sf = grid(_rotated(fine, sample)).mean(axis=1)
            R = yaw_matrix(fine[int(np.argmin(sf))])
            R, t = _planar_icp(icp_src, tree, self.clouds[j], R, np.zeros(3))
            fwd = tree.query(obs @ R.T + t, distance_upper_bound=_CAP)[0]
            # cached points taken back into the observed cloud's frame
            back_pts = (self.clouds[j] - t) @ R
            back = obs_tree.query(back_pts, distance_upper_bound=_CAP)[0]
            a = Alignment(int(j), R, t, fwd, back)
            if stop_at is not None and a.fraction(self.tolerance) >= stop_at:
                return obs, mean, [a]
            out.append(a)
        out.sort(key=lambda a: -a.fraction(self.tolerance))
        return obs, mean, out

    def recognise(self, points: np.ndarray) -> tuple[Match, np.ndarray]:
        """Match object points (table frame) against the cache.

        Returns (the match, the cloud in the pose frame it would have as a new
        pose). The library is not changed (call :meth:`add` for a new pose)."""
        stop = self.match_fraction if self.first_match else None
        obs, mean, aligned = self.align(points, stop_at=stop)
        new_tf = np.eye(4)
        new_tf[:3, 3] = -mean
        if not aligned:
            return Match(None, new_tf, 0.0, None, 0), obs
        best = aligned[0]
        frac = best.fraction(self.tolerance)
        if frac >= self.match_fraction:
            tf = np.eye(4)
            tf[:3, :3] = best.R
            tf[:3, 3] = best.t - best.R @ mean
            return Match(best.pose, tf, frac, best.pose, len(aligned)), obs
        return Match(None, new_tf, frac, best.pose, len(aligned)), obs
