"""Antipodal grasps sampled on a depth image, and the prior that scores them.

The sampler follows GQ-CNN's ``antipodal_depth`` sampler: depth gradients of the
(Gaussian-smoothed) image mark the object's edges; each edge pixel's outward
normal is the direction in which the depth grows (mapped to the table plane);
pairs of edge pixels closer than the gripper opening whose normals both lie in
the friction cone of the line joining them (μ = ``FRICTION``, as GQ-CNN's
default 1.0: a 45° cone) are antipodal pairs. Each pair gives grasps at a few
closing heights, ``DEPTH_OFFSETS`` below the lower of its two contact heights;
a grasp whose fingers would land on the object (the observed height under either
open finger, dilated by the finger radius, above the finger tip) is dropped.

Every grasp is a top-down parallel-jaw grasp in the table frame: centre (x, y at
the middle of the contacts, z the closing height), unit horizontal jaw axis, and
width (the contact distance).

The prior
---------
New poses are scored by the learned prior (the GQ-CNN-style network of
:mod:`precompute.gqcnn`, the weights ``precompute`` scores the problem files with),
from the session's own depth image: :func:`prior_view` turns the image into the
view the network was trained on (the camera of :mod:`precompute.depth`, 0.7 m
straight above the object, 4 mm pixels at the table: the image's table-frame
points, shifted so that the visible object's centroid is under that camera,
projected into it and averaged per pixel, as ``precompute.depth.downsample``
averages 3 × 3 sensor pixels; pixels no point falls into take their nearest
neighbour's value), and :func:`learned_prior` cuts each grasp's crop there. It
reads nothing but the image and the grasps. A camera of another geometry works
through the same resampling, but the network was trained on views of that one
camera and its noise only.

When the weights are missing (a checkout without ``precompute/prior_weights``),
:func:`default_prior` falls back to :func:`geometric_prior`, a stand-in that
reads the edge normals alone (how antipodal the two contacts are, mapped to
[0.3, 0.7]) and says so in a warning and in the session's records. Any function
``f(grasps, view) -> q [K]`` plugs in as the prior (``Session.create(prior=f)``),
``view`` a :class:`View` of the image the grasps were sampled on.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from legs_jax.online.camera import Intrinsics, deproject
from legs_jax.online.recognition import MIN_HEIGHT
from precompute import depth as D
from precompute import grasps as G
from precompute import learned

__all__ = [
    "DEFAULT_PRIOR",
    "DEPTH_OFFSETS",
    "FRICTION",
    "PRIORS",
    "Grasps",
    "View",
    "default_prior",
    "geometric_prior",
    "learned_prior",
    "prior_name",
    "prior_view",
    "sample_grasps",
]

FRICTION = 1.0
GRADIENT_THRESHOLD = 0.0025  # m of depth per pixel (GQ-CNN's depth_grad_thresh)
GRADIENT_SIGMA = 1.0  # pixels
MAX_EDGES = 1500  # edge pixels considered (a random subset when there are more)
DEPTH_OFFSETS = (0.004, 0.012, 0.02)  # closing heights below the contacts (m)
MIN_WIDTH = 0.004  # m


@dataclasses.dataclass(frozen=True)
class Grasps:
    """K grasps in one frame (table or pose frame)."""

    center: np.ndarray  # [K, 3]
    axis: np.ndarray  # [K, 3] unit, horizontal
    width: np.ndarray  # [K]
    alignment: np.ndarray  # [K] in [0, 1]: how antipodal the edge normals are

    def __len__(self) -> int:
        return len(self.width)

    def transformed(self, tf: np.ndarray) -> Grasps:
        """The grasps under the rigid transform ``tf`` [4, 4]."""
        R, t = tf[:3, :3], tf[:3, 3]
        return dataclasses.replace(
            self, center=self.center @ R.T + t, axis=self.axis @ R.T
        )


class View(NamedTuple):
    """The image a pose's grasps were sampled on."""

    depth: np.ndarray  # [H, W] metres, NaN where there is no reading
    intrinsics: Intrinsics
    camera_pose: np.ndarray  # [4, 4] camera -> table


def geometric_prior(grasps: Grasps, view: View | None = None) -> np.ndarray:
    """[K] stand-in prior quality in [0.3, 0.7] from the edge normals alone."""
    return 0.3 + 0.4 * np.clip(grasps.alignment, 0.0, 1.0)


def prior_view(view: View):
    """(image, offset): the session's depth image as the learned prior's camera
    would see it (a :class:`precompute.depth.DepthImage` of 4 mm pixels, the
    camera 0.7 m above the object) and the table-frame offset [3] (the visible
    object's centroid in x and y) to subtract from grasp centres for it."""
    pts = deproject(view.depth, view.intrinsics, view.camera_pose).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    obj = pts[:, 2] > MIN_HEIGHT
    if not obj.any():
        raise ValueError("no object in view")
    offset = np.array([*pts[obj, :2].mean(axis=0), 0.0])
    pts = pts - offset
    pts = pts[pts[:, 2] < D.HEIGHT - 0.05]  # in front of the camera
    f = D.DOWNSAMPLE
    uv_obj = D.project(pts[pts[:, 2] > MIN_HEIGHT])
    lo = np.floor(uv_obj.min(axis=0)) - D.MARGIN_PX
    hi = np.ceil(uv_obj.max(axis=0)) + D.MARGIN_PX
    w, h = (np.ceil((hi - lo + 1) / f)).astype(int)
    u0, v0 = lo + (f - 1) / 2.0  # centre of resized pixel [0, 0] (sensor u, v)
    uv = D.project(pts)
    col = np.rint((uv[:, 0] - u0) / f).astype(np.int64)
    row = np.rint((uv[:, 1] - v0) / f).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    cell = row[inside] * w + col[inside]
    depth = D.HEIGHT - pts[inside, 2]
    total = np.bincount(cell, weights=depth, minlength=h * w)
    count = np.bincount(cell, minlength=h * w)
    img = np.full(h * w, np.nan)
    img[count > 0] = total[count > 0] / count[count > 0]
    img = img.reshape(h, w)
    missing = np.isnan(img)
    if missing.all():
        raise ValueError("the image holds no point near the object")
    if missing.any():
        idx = ndimage.distance_transform_edt(
            missing, return_distances=False, return_indices=True
        )
        img = img[tuple(idx)]
    return D.DepthImage(img.astype(np.float32), float(u0), float(v0), f), offset


def learned_prior(grasps: Grasps, view: View) -> np.ndarray:
    """[K] q of table-frame grasps from the learned prior's network, seen in
    ``view`` (:func:`prior_view`); the weights :mod:`precompute.learned` ships."""
    if len(grasps) == 0:
        return np.zeros(0)
    image, offset = prior_view(view)
    centers = (grasps.center - offset).astype(np.float32)
    return learned.scorer()(image, centers, grasps.axis.astype(np.float32))


# The priors a session can name, and the default.
PRIORS = {"learned": learned_prior, "geometric": geometric_prior}
DEFAULT_PRIOR = "learned"


def default_prior(name: str = DEFAULT_PRIOR):
    """The prior named ``name`` (a key of :data:`PRIORS`); the learned prior
    falls back to the geometric stand-in, with a warning that says so, where
    its weights are missing."""
    if name not in PRIORS:
        raise ValueError(f"unknown prior {name!r}; one of {', '.join(PRIORS)}")
    if PRIORS[name] is learned_prior and not learned.available():
        warnings.warn(
            "the learned prior's weights are missing (precompute/prior_weights): new "
            "poses are scored by the geometric stand-in prior",
            stacklevel=2,
        )
        return geometric_prior
    return PRIORS[name]


def prior_name(prior) -> str:
    """How a prior is named in the session's records."""
    for name, f in PRIORS.items():
        if prior is f:
            return name
    return f"custom: {getattr(prior, '__qualname__', type(prior).__name__)}"


def _empty() -> Grasps:
    z = np.zeros((0, 3))
    return Grasps(z, z, np.zeros(0), np.zeros(0))


def sample_grasps(
    depth: np.ndarray,
    intr: Intrinsics,
    camera_pose: np.ndarray,
    num_grasps: int,
    rng: np.random.Generator,
) -> Grasps:
    """Up to ``num_grasps`` antipodal grasps (table frame) on a depth image
    (metres, NaN where there is no reading)."""
    pts = deproject(depth, intr, camera_pose)  # [H, W, 3]
    height = np.nan_to_num(pts[..., 2], nan=0.0)
    obj = height > MIN_HEIGHT
    d = np.where(np.isfinite(depth), depth, np.nanmax(depth))
    ds = ndimage.gaussian_filter(d, GRADIENT_SIGMA)
    gv, gu = np.gradient(ds)  # per pixel, along v (rows) and u (columns)
    mag = np.hypot(gu, gv)
    edge = obj & (mag > GRADIENT_THRESHOLD)
    vv, uu = np.nonzero(edge)
    if len(uu) < 2:
        return _empty()
    if len(uu) > MAX_EDGES:
        pick = rng.choice(len(uu), MAX_EDGES, replace=False)
        vv, uu = vv[pick], uu[pick]
    # the table-plane directions of one pixel step along u and v at the object
    z_med = float(np.median(depth[obj])) if obj.any() else float(np.nanmedian(depth))
    ray = intr.rays()
    R = camera_pose[:3, :3]
    c_v, c_u = int(round(intr.cy)), int(round(intr.cx))
    c_v = min(max(c_v, 0), intr.height - 2)
    c_u = min(max(c_u, 0), intr.width - 2)
    p0 = R @ (ray[c_v, c_u] * z_med)
    ju = (R @ (ray[c_v, c_u + 1] * z_med) - p0)[:2]
    jv = (R @ (ray[c_v + 1, c_u] * z_med) - p0)[:2]
    J = np.stack([ju, jv], axis=1)  # d(xy)/d(u, v)
    grad_uv = np.stack([gu[vv, uu], gv[vv, uu]], axis=1)
    normal = grad_uv @ np.linalg.inv(J)  # ∇_xy depth = J^-T ∇_uv depth (as rows)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    xy = pts[vv, uu, :2]
    zc = height[vv, uu]
    # every pair (i, j): contact i pushed along +v, contact j along -v
    diff = xy[None, :, :] - xy[:, None, :]  # [n, n, 2] from i to j
    dist = np.linalg.norm(diff, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = diff / dist[..., None]
    cos_cone = 1.0 / np.sqrt(1.0 + FRICTION**2)
    ni = -np.einsum("ik,ijk->ij", normal, v)  # -n_i · v
    nj = np.einsum("jk,ijk->ij", normal, v)  # n_j · v
    ok = (dist >= MIN_WIDTH) & (dist <= G.OPENING - 0.01)
    ok &= (ni >= cos_cone) & (nj >= cos_cone)
    ok &= np.triu(np.ones_like(ok), 1)
    ii, jj = np.nonzero(ok)
    if len(ii) == 0:
        return _empty()
    # a random order of (pair, closing height)
    n_off = len(DEPTH_OFFSETS)
    total = len(ii) * n_off
    take = rng.permutation(total)[: 4 * num_grasps]
    pair, off = take // n_off, take % n_off
    i, j = ii[pair], jj[pair]
    h = np.minimum(zc[i], zc[j]) - np.asarray(DEPTH_OFFSETS)[off]
    h = np.maximum(h, G.MIN_HEIGHT)
    axis2 = v[i, j]
    center = np.concatenate([0.5 * (xy[i] + xy[j]), h[:, None]], axis=1)
    axis = np.concatenate([axis2, np.zeros((len(i), 1))], axis=1)
    width = dist[i, j]
    align = 0.5 * (ni[i, j] + nj[i, j])
    align = (align - cos_cone) / (1.0 - cos_cone)
    # drop grasps whose open fingers would land on the observed object
    keep = _fingers_clear(height, center, axis, intr, camera_pose)
    keep &= zc[i] - h > 0.0
    sel = np.flatnonzero(keep)[:num_grasps]
    return Grasps(center[sel], axis[sel], width[sel], align[sel])


def _fingers_clear(height, center, axis, intr, camera_pose) -> np.ndarray:
    """[N] the observed height under both open fingers (within the finger radius)
    stays below the finger tip."""
    z_med = camera_pose[2, 3]
    r_px = int(np.ceil(G.FINGER_RADIUS * max(intr.fx, intr.fy) / max(z_med, 0.05)))
    yy, xx = np.mgrid[-r_px : r_px + 1, -r_px : r_px + 1]
    disk = xx**2 + yy**2 <= r_px**2
    dil = ndimage.maximum_filter(height, footprint=disk, mode="constant", cval=0.0)
    tip = center[:, 2] - G.TIP_BELOW
    inv = np.linalg.inv(camera_pose)
    ok = np.ones(len(center), bool)
    for sign in (-1.0, 1.0):
        f = center.copy()
        f[:, :2] += sign * (G.OPENING / 2 + G.FINGER_RADIUS) * axis[:, :2]
        f[:, 2] = 0.0
        pc = f @ inv[:3, :3].T + inv[:3, 3]
        uv = intr.project(pc)
        u = np.clip(np.rint(uv[:, 0]).astype(int), 0, intr.width - 1)
        v = np.clip(np.rint(uv[:, 1]).astype(int), 0, intr.height - 1)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < intr.width)
        inside &= (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
        ok &= inside & (dil[v, u] <= tip)
    return ok
