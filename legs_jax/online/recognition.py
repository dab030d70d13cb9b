"""Stable-pose recognition from depth images (the paper's Section 6).

Depth image → table-frame point cloud with the intrinsics and the camera pose →
the object's points (more than ``MIN_HEIGHT`` above the table) on a ``VOXEL``
grid → demeaned in x and y (the table fixes z, so heights stay comparable). The
cloud is compared with every cached pose's cloud over 3600 yaws (0.1°) about the
vertical (the optical axis of an overhead camera) by the observed → cached half
of the chamfer distance, searched coarse to fine: all 360 whole degrees, then the
0.1° yaws within ±1° of the best ``REFINE`` coarse ones (a 1° step moves a point
5 cm from the centre by 0.9 mm, under the tolerance). The best yaw is refined by
trimmed ICP (rotation about the vertical and a translation; the 80 % closest
pairs). The clouds show the same pose when at least ``MATCH_FRACTION`` = 80 % of
the observed points lie within ``TOLERANCE`` of the cached cloud and 80 % of the
cached points within it of the observed cloud (both ways, so that a cloud that
covers only part of another is no match). Otherwise the cloud is cached as a new
pose.

The paper prints a tolerance of 0.02 mm, far below the noise of any depth sensor
(about 1 mm here). We use ``TOLERANCE`` = 3 mm: about three standard deviations of
the simulated sensor noise, and under the height differences that separate the
stable poses of the Dex-Net objects (see results/online/recognition.md).

Nearest neighbours come from SciPy's ``cKDTree`` (one tree per cached pose).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from legs_jax.online.camera import Intrinsics, deproject
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

TOLERANCE = 0.003  # m
MATCH_FRACTION = 0.8
MIN_HEIGHT = 0.004  # m above the table: object points
VOXEL = 0.002  # m
MIN_POINTS = 30  # fewer object voxels: no object in view
SEARCH_POINTS = 256  # observed points scored at each of the coarse yaws
REFINE = 3
ICP_ITERATIONS = 15
ICP_KEEP = 0.8
_CAP = 0.02  # distances are capped here in the chamfer score (outliers)


def object_cloud(
    depth: np.ndarray, intr: Intrinsics, camera_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(points [N, 3] of the object on the voxel grid, table frame; mask [H, W] of
    the object's pixels). Raises :class:`InputError` when no object is in view."""
    pts = deproject(depth, intr, camera_pose)
    mask = np.isfinite(pts[..., 2]) & (pts[..., 2] > MIN_HEIGHT)
    p = pts[mask]
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
    """One point (the mean) per occupied voxel."""
    idx = np.floor(p / voxel).astype(np.int64)
    _, inv, counts = np.unique(idx, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out = np.zeros((len(counts), 3))
    np.add.at(out, inv, p)
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


def _score(tree: cKDTree, pts: np.ndarray) -> np.ndarray:
    d, _ = tree.query(pts, distance_upper_bound=_CAP)
    return np.minimum(d, _CAP)


def _planar_icp(src: np.ndarray, tree: cKDTree, dst: np.ndarray, R, t):
    """Trimmed ICP with a yaw rotation and a 3-D translation, from (R, t)."""
    for _ in range(ICP_ITERATIONS):
        cur = src @ R.T + t
        d, j = tree.query(cur)
        keep = d <= np.quantile(d, ICP_KEEP)
        a, b = src[keep], dst[j[keep]]
        ma, mb = a.mean(0), b.mean(0)
        A, B = a[:, :2] - ma[:2], b[:, :2] - mb[:2]
        yaw = np.arctan2(np.sum(A[:, 0] * B[:, 1] - A[:, 1] * B[:, 0]), np.sum(A * B))
        R_new = yaw_matrix(yaw)
        t_new = mb - R_new @ ma
        done = np.allclose(R_new, R, atol=1e-7) and np.allclose(t_new, t, atol=1e-7)
        R, t = R_new, t_new
        if done:
            break
    return R, t


class PoseLibrary:
    """The cached clouds of the poses seen so far (pose frames: demeaned in x, y)."""

    def __init__(self, seed: int = 0):
        self.clouds: list[np.ndarray] = []
        self._trees: list[cKDTree] = []
        self._tops: list[float] = []
        self._seed = seed

    def __len__(self) -> int:
        return len(self.clouds)

    def add(self, cloud: np.ndarray) -> int:
        """Cache ``cloud`` (pose frame) as a new pose; its index."""
        c = np.asarray(cloud, np.float64)
        self.clouds.append(c)
        self._trees.append(cKDTree(c))
        self._tops.append(float(np.quantile(c[:, 2], 0.95)))
        return len(self.clouds) - 1

    def recognise(self, points: np.ndarray) -> tuple[Match, np.ndarray]:
        """Match object points (table frame) against the cache.

        Returns (the match, the cloud in the pose frame it would have as a new
        pose). The library is not changed (call :meth:`add` for a new pose)."""
        mean = points.mean(0)
        mean[2] = 0.0
        obs = points - mean
        new_tf = np.eye(4)
        new_tf[:3, 3] = -mean
        if not self.clouds:
            return Match(None, new_tf, 0.0, None, 0), obs
        rng = np.random.default_rng(self._seed)
        n = len(obs)
        sample = obs[rng.choice(n, min(n, SEARCH_POINTS), replace=False)]
        top = float(np.quantile(obs[:, 2], 0.95))
        coarse = np.deg2rad(np.arange(360.0))
        rot_c = yaw_matrix(coarse)  # [360, 3, 3]
        best = (-1.0, None, None, None)
        compared = 0
        order = np.argsort([abs(t - top) for t in self._tops])
        for j in order:
            if abs(self._tops[j] - top) > 4 * TOLERANCE:
                continue  # the heights alone tell them apart
            compared += 1
            tree = self._trees[j]
            rs = np.einsum("aij,nj->ani", rot_c, sample)
            sc = _score(tree, rs.reshape(-1, 3)).reshape(len(coarse), -1).mean(1)
            fine = []
            for a in coarse[np.argsort(sc)[:REFINE]]:
                fine.append(a + np.deg2rad(np.arange(-10, 11) * 0.1))
            fine = np.concatenate(fine)
            rot_f = yaw_matrix(fine)
            rs = np.einsum("aij,nj->ani", rot_f, sample)
            sf = _score(tree, rs.reshape(-1, 3)).reshape(len(fine), -1).mean(1)
            R = rot_f[int(np.argmin(sf))]
            # the translation that matches the means at this yaw
            t = self.clouds[j].mean(0) - R @ obs.mean(0)
            t[:2] = 0.0
            t[2] = 0.0
            R, t = _planar_icp(obs, tree, self.clouds[j], R, t)
            cur = obs @ R.T + t
            fwd = float(
                np.mean(tree.query(cur, distance_upper_bound=_CAP)[0] < TOLERANCE)
            )
            back_d, _ = cKDTree(cur).query(self.clouds[j], distance_upper_bound=_CAP)
            frac = min(fwd, float(np.mean(back_d < TOLERANCE)))
            if frac > best[0]:
                best = (frac, int(j), R, t)
        frac, j, R, t = best
        if j is None:
            return Match(None, new_tf, 0.0, None, compared), obs
        if frac >= MATCH_FRACTION:
            tf = np.eye(4)
            tf[:3, :3] = R
            tf[:3, 3] = t - R @ mean
            return Match(j, tf, frac, j, compared), obs
        return Match(None, new_tf, frac, j, compared), obs
