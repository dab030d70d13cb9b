"""Top-down parallel-jaw grasps: the gripper, the reservoir sampler, ground truth.

Gripper (all lengths in metres, in the pose frame: table at z = 0, z up)
-------------------------------------------------------------------------
A parallel-jaw gripper approaching vertically from above, jaw axis horizontal
(a Franka-Panda-like hand; the paper leaves the opening to us, "≈ 0.08 m"):

- ``OPENING`` = 0.08: distance between the two finger pads when open (the Franka
  Hand opens 80 mm).
- Each finger is a vertical bar whose pad (the face that touches the object) is
  probed at ``PAD_HEIGHTS`` = 0 and 10 mm above the grasp height h; its tip is
  ``TIP_BELOW`` = 2 mm below h. For collisions a finger is a vertical cylinder of
  radius ``FINGER_RADIUS`` = 6 mm just outside its pad.
- The pad is as wide as the finger: the contact normal it feels is the normal of
  the surface's plane under a disc of radius ``PAD_RADIUS`` = ``FINGER_RADIUS``
  around the contact (:func:`precompute.raycast.face_pad_normals`), not the normal
  of one facet of the mesh.
- The palm is ``FINGER_LENGTH`` = 50 mm above the finger tips and spans the gap
  between the fingers (width 2 × FINGER_RADIUS).

A grasp is (centre c, unit horizontal axis a): the jaws open at c ± (OPENING / 2) a
descend to height h = c_z and close along a.

Executing a grasp (nominal or perturbed)
----------------------------------------
1. Descent: it fails if either finger cylinder or the palm would meet the object on
   the way down: the object's height map (one downward ray per 1 mm cell, dilated by
   the finger radius) must stay below the finger tip under each finger and below the
   palm over the gap. Finger tips below the table fail too.
2. Closing: each finger's pad sweeps towards the other; one ray per pad height and
   finger is cast by Embree from the open pad position along ±a; the finger stops at
   the nearest hit, and of the pad points within ``PAD_COMPLIANCE`` (0.5 mm) of that
   first touch the one whose pad normal best opposes the squeeze is the contact. A
   finger that meets nothing within the opening, or starts inside the object (first
   hit on a face turned away), fails.
3. Force closure of the two contacts (points with Coulomb friction, Nguyen's
   two-finger test, as Dex-Net's ``quality.py``): the line joining the contacts lies
   inside both friction cones, -n₁·v ≥ cos(atan μ) and n₂·v ≥ cos(atan μ), with n
   the outward pad normals and v the unit vector from contact 1 to contact 2.
   Contacts under the table fail.

Ground truth p: the fraction of ``SAMPLES`` = 50 perturbed executions that
succeed; each sample draws a planar translation of the gripper relative to the
object (σ = ``SIGMA_TRANSLATION`` = 10 mm / √2 ≈ 7.07 mm per horizontal axis, so
10 mm root-mean-square in the plane; Dex-Net's configurations use 5-10 mm), a yaw
(σ = ``SIGMA_YAW`` = 0.05 rad, about the vertical through c) and a friction
coefficient μ ~ N(0.5, 0.1) clipped to [0, 1] (Dex-Net 2.0). Contacts are
recomputed by ray casting for every sample. All rays of a pose go through a few
large Embree calls.

Reservoir sampler (antipodal, as Dex-Net's and GQ-CNN's)
--------------------------------------------------------
Per trial and pose, candidates are drawn from the pose's geometry: a point x on a
side face (pad normal with |n_z| < ``SIDE_FACE_NZ``, area-weighted, x_z ≥
``MIN_HEIGHT``), an axis pointing into the surface (the horizontal part of the pad
normal -n) turned by a yaw uniform in ±``AXIS_SPREAD`` = ±atan(μ_s), the friction
cone's half-angle (Dex-Net's antipodal sampler draws the axis inside the cone,
BerkeleyAutomation/dex-net ``src/dexnet/grasping/grasp_sampler.py``), and the jaw
centre midway across the object's chord through x along the axis. A candidate
enters the reservoir only when its nominal execution reaches two contacts without
collision and those two contacts pass the force-closure test at the sampling
friction μ_s = ``SAMPLING_FRICTION`` = 0.6 (Dex-Net 2.0's antipodal rejection
sampling, RSS 2017 §IV-A). Nominal force closure is not robustness: under the
perturbations above many antipodal grasps slip off an edge or a narrow face, so a
reservoir holds both good and bad grasps. Candidates are drawn in rounds of 2K
until K are accepted or ``MAX_ROUNDS`` rounds are spent; then the rest of the slots
are padding (``valid`` False).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .raycast import RayCaster

__all__ = [
    "OPENING",
    "FINGER_RADIUS",
    "FINGER_LENGTH",
    "PAD_HEIGHTS",
    "TIP_BELOW",
    "MIN_HEIGHT",
    "AXIS_SPREAD",
    "PAD_RADIUS",
    "SAMPLING_FRICTION",
    "MAX_ROUNDS",
    "SAMPLES",
    "SIGMA_TRANSLATION",
    "SIGMA_YAW",
    "FRICTION_MEAN",
    "FRICTION_SD",
    "HeightMap",
    "Reservoir",
    "gripper_params",
    "height_map",
    "execute",
    "sample_reservoir",
    "perturbations",
    "robustness",
]

OPENING = 0.08
FINGER_RADIUS = 0.006
FINGER_LENGTH = 0.05
PAD_HEIGHTS = (0.0, 0.01)
PAD_LATERAL = (0.0,)
PAD_COMPLIANCE = 0.0005
TIP_BELOW = 0.002
MIN_HEIGHT = 0.005
PAD_RADIUS = FINGER_RADIUS
SAMPLING_FRICTION = 0.6
AXIS_SPREAD = float(np.arctan(SAMPLING_FRICTION))
MAX_ROUNDS = 20
SIDE_FACE_NZ = 0.95

SAMPLES = 50
SIGMA_TRANSLATION = 0.01 / np.sqrt(2.0)
SIGMA_YAW = 0.05
FRICTION_MEAN = 0.5
FRICTION_SD = 0.1

_GRID = 0.001  # height-map cell (m)
_PALM_POINTS = 15
_SAMPLE_CHUNK = 100_000  # perturbed executions per Embree round


def gripper_params() -> dict:
    """Every constant of the gripper and the perturbation model (for hashing/meta)."""
    return {
        "opening": OPENING,
        "finger_radius": FINGER_RADIUS,
        "finger_length": FINGER_LENGTH,
        "pad_heights": list(PAD_HEIGHTS),
        "tip_below": TIP_BELOW,
        "min_height": MIN_HEIGHT,
        "axis_spread_rad": float(AXIS_SPREAD),
        "pad_radius": PAD_RADIUS,
        "sampling_friction": SAMPLING_FRICTION,
        "antipodal": True,
        "max_rounds": MAX_ROUNDS,
        "side_face_nz": SIDE_FACE_NZ,
        "sigma_translation": SIGMA_TRANSLATION,
        "sigma_yaw": SIGMA_YAW,
        "friction_mean": FRICTION_MEAN,
        "friction_sd": FRICTION_SD,
        "height_map_cell": _GRID,
    }


@dataclasses.dataclass(frozen=True, eq=False)
class HeightMap:
    """Top surface of the object in one pose, dilated by the finger radius."""

    origin: np.ndarray  # [2] x, y of cell (0, 0)
    cell: float
    height: np.ndarray  # [NX, NY] max object height within FINGER_RADIUS (0: table)

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """[...] dilated height at points xy [..., 2]. The map's border cells are
        table (0), and points off the map read the nearest border cell."""
        nx, ny = self.height.shape
        i = np.clip(np.rint((xy[..., 0] - self.origin[0]) / self.cell), 0, nx - 1)
        j = np.clip(np.rint((xy[..., 1] - self.origin[1]) / self.cell), 0, ny - 1)
        flat = i.astype(np.int64) * ny + j.astype(np.int64)
        return self.height.ravel()[flat]

    @property
    def top(self) -> float:
        return float(self.height.max())


def height_map(caster: RayCaster) -> HeightMap:
    """Cast one downward ray per cell over the posed object and its surroundings
    (``caster``: the scene of the mesh in the pose frame)."""
    from scipy import ndimage

    v = caster.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    margin = OPENING / 2 + 2 * FINGER_RADIUS + 5 * SIGMA_TRANSLATION
    x = np.arange(lo[0] - margin, hi[0] + margin + _GRID, _GRID)
    y = np.arange(lo[1] - margin, hi[1] + margin + _GRID, _GRID)
    gx, gy = np.meshgrid(x, y, indexing="ij")
    top = hi[2] + 0.01
    origins = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, top)], axis=1)
    dirs = np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape)
    t, _ = caster.cast(origins, dirs)
    h = np.where(np.isfinite(t), top - t, 0.0).reshape(gx.shape)
    r = int(np.ceil(FINGER_RADIUS / _GRID))
    di, dj = np.mgrid[-r : r + 1, -r : r + 1]
    disk = di**2 + dj**2 <= (FINGER_RADIUS / _GRID) ** 2
    h = ndimage.maximum_filter(h, footprint=disk, mode="constant", cval=0.0)
    h[[0, -1], :] = 0.0  # the border is table (the margin is wider than the finger)
    h[:, [0, -1]] = 0.0
    return HeightMap(np.array([x[0], y[0]]), _GRID, h)


@dataclasses.dataclass
class Execution:
    """Outcome of executing N grasps (nominal or perturbed). Contacts are kept for
    the executions that reached the closing stage only (``live``)."""

    ok: np.ndarray  # [N] bool, no collision and two contacts found
    live: np.ndarray  # [L] indices of the executions whose descent was clear
    x1: np.ndarray  # [L, 3] contact of finger 1 (the -a side)
    x2: np.ndarray  # [L, 3] contact of finger 2
    n1: np.ndarray  # [L, 3] outward normal at x1
    n2: np.ndarray  # [L, 3] outward normal at x2


def execute(
    caster: RayCaster,
    hmap: HeightMap,
    centers: np.ndarray,
    axes: np.ndarray,
) -> Execution:
    """Descend and close the gripper for each (centre [N, 3], unit axis [N, 3]),
    in the pose frame of ``caster`` and ``hmap``. Rays are cast only for the
    executions whose descent is clear."""
    c = np.asarray(centers, np.float32)
    a = np.asarray(axes, np.float32)
    tip = c[:, 2] - np.float32(TIP_BELOW)
    half = np.float32(OPENING / 2)
    # 1. descent: fingers and palm against the dilated height map
    reach = np.float32(OPENING / 2 + FINGER_RADIUS) * a[:, :2]
    clear = tip >= 0.0
    clear &= hmap.lookup(c[:, :2] - reach) <= tip
    clear &= hmap.lookup(c[:, :2] + reach) <= tip
    # the palm can only meet an object taller than the palm height
    low = np.flatnonzero(clear & (tip + np.float32(FINGER_LENGTH) < hmap.top))
    if low.size:
        s = np.linspace(-half, half, _PALM_POINTS, dtype=np.float32)
        palm = c[low, None, :2] + s[None, :, None] * a[low, None, :2]
        clear[low] = hmap.lookup(palm).max(axis=1) <= tip[low] + FINGER_LENGTH
    # 2. closing: one ray per pad point and finger, for the clear executions only
    live = np.flatnonzero(clear)
    found, outside, x1, x2, n1, n2 = _close(caster, c[live], a[live])
    ok = clear
    ok[live] = found & outside
    return Execution(ok, live, x1, x2, n1, n2)


def _pad_points() -> np.ndarray:
    """[m, 2] (lateral, vertical) offsets of the pad points from the grasp line."""
    lat, up = np.meshgrid(PAD_LATERAL, PAD_HEIGHTS, indexing="ij")
    return np.stack([lat.ravel(), up.ravel()], axis=1)


def _close(caster: RayCaster, c: np.ndarray, a: np.ndarray):
    """Close both pads from the open position; see the module docstring."""
    nl = len(c)
    half = OPENING / 2
    pad = _pad_points()
    m = len(pad)
    c32 = c.astype(np.float32)
    a32 = a.astype(np.float32)
    b = np.stack([-a32[:, 1], a32[:, 0], np.zeros(nl, np.float32)], axis=1)
    off = pad[None, :, 0, None].astype(np.float32) * b[:, None, :]  # [n, m, 3]
    off[..., 2] += pad[None, :, 1].astype(np.float32)
    start1 = (c32 - half * a32)[:, None, :] + off
    start2 = (c32 + half * a32)[:, None, :] + off
    origins = np.concatenate([start1, start2]).reshape(-1, 3)
    dirs = np.broadcast_to(
        np.concatenate([a32, -a32])[:, None, :], (2 * nl, m, 3)
    ).reshape(-1, 3)
    t, prim = caster.cast_raw(origins, dirs)
    t = t.reshape(2, nl, m)
    prim = prim.reshape(2, nl, m)
    face = caster.normals_of(prim, np.float32)  # [2, n, m, 3] facet normals
    nrm = caster.pad_normals_of(prim, PAD_RADIUS)  # what the pad feels
    face_along = (
        face[..., 0] * a32[None, :, None, 0]
        + face[..., 1] * a32[None, :, None, 1]
        + face[..., 2] * a32[None, :, None, 2]
    )  # n·a of the facet hit
    along = (
        nrm[..., 0] * a32[None, :, None, 0]
        + nrm[..., 1] * a32[None, :, None, 1]
        + nrm[..., 2] * a32[None, :, None, 2]
    )  # n·a of the pad normal
    idx = np.arange(nl)
    if m == 1:
        near = np.zeros((2, nl), np.int64)
        tmin = t[..., 0]
    else:
        near = np.argmin(t, axis=2)  # [2, n] the pad point that touches first
        tmin = np.take_along_axis(t, near[..., None], axis=2)[..., 0]
    found = (tmin[0] <= OPENING) & (tmin[1] <= OPENING)
    # the pad starts inside the object when its first hit is a face turned away
    out = (face_along[0, idx, near[0]] < 0) & (face_along[1, idx, near[1]] > 0)
    if m == 1:
        k = near
    else:
        # the compliant pad touches every point within PAD_COMPLIANCE of the first
        # touch; of those, the contact whose normal best opposes the squeeze counts
        touching = t <= tmin[..., None] + PAD_COMPLIANCE
        along[0] = -along[0]
        k = np.argmax(np.where(touching, along, -np.inf), axis=2)  # [2, n]
    ta = np.where(found, t[0, idx, k[0]], 0.0)[:, None]
    tb = np.where(found, t[1, idx, k[1]], 0.0)[:, None]
    x1 = start1[idx, k[0]] + ta * a32
    x2 = start2[idx, k[1]] - tb * a32
    return found, out, x1, x2, nrm[0, idx, k[0]], nrm[1, idx, k[1]]


def force_closure(ex: Execution, mu: np.ndarray) -> np.ndarray:
    """[N] two-contact force closure with friction coefficients mu [N]."""
    live = ex.live
    v = ex.x2 - ex.x1
    length = np.sqrt((v * v).sum(axis=1))
    v = v / np.maximum(length, 1e-12)[:, None]
    cos_cone = 1.0 / np.sqrt(1.0 + mu[live] ** 2)  # cos(atan μ)
    c1 = -(ex.n1 * v).sum(axis=1) >= cos_cone
    c2 = (ex.n2 * v).sum(axis=1) >= cos_cone
    above = (ex.x1[:, 2] >= 0.0) & (ex.x2[:, 2] >= 0.0)
    out = np.zeros(len(ex.ok), bool)
    out[live] = ex.ok[live] & c1 & c2 & above & (length > 0)
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class Reservoir:
    """K grasp slots of one trial and pose (padding where ``valid`` is False)."""

    valid: np.ndarray  # [K] bool
    center: np.ndarray  # [K, 3] jaw centre (pose frame)
    axis: np.ndarray  # [K, 3] unit horizontal jaw axis
    width: np.ndarray  # [K] nominal contact-to-contact distance
    candidates: int  # candidates drawn


def _side_faces(caster: RayCaster):
    tri = caster.vertices[caster.faces]  # [F, 3, 3]
    nrm = caster.pad_normals_of(np.arange(len(caster.faces)), PAD_RADIUS).astype(
        np.float64
    )
    area = 0.5 * np.linalg.norm(
        np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1
    )
    # keep faces that are mostly upright and reach above MIN_HEIGHT
    side = (np.abs(nrm[:, 2]) < SIDE_FACE_NZ) & (tri[:, :, 2].max(axis=1) >= MIN_HEIGHT)
    idx = np.flatnonzero(side & (area > 0))
    return tri[idx], nrm[idx], area[idx]


def sample_reservoir(
    caster: RayCaster,
    hmap: HeightMap,
    num_grasps: int,
    rng: np.random.Generator,
) -> Reservoir:
    """Up to ``num_grasps`` antipodal grasps of one pose (``caster``: the posed
    mesh), drawn with ``rng`` (see the module docstring)."""
    tri, nrm, area = _side_faces(caster)
    K = num_grasps
    center = np.zeros((K, 3))
    axis = np.zeros((K, 3))
    width = np.zeros(K)
    count = 0
    drawn = 0
    if len(tri) == 0:
        return Reservoir(np.zeros(K, bool), center, axis, width, 0)
    prob = area / area.sum()
    batch = 2 * K
    for _ in range(MAX_ROUNDS):
        if count >= K:
            break
        f = rng.choice(len(tri), size=batch, p=prob)
        r1, r2 = rng.random(batch), rng.random(batch)
        yaw = rng.uniform(-AXIS_SPREAD, AXIS_SPREAD, batch)
        drawn += batch
        sq = np.sqrt(r1)
        w = np.stack([1 - sq, sq * (1 - r2), sq * r2], axis=1)
        x = np.einsum("ij,ijk->ik", w, tri[f])
        nh = -nrm[f, :2]
        nh /= np.linalg.norm(nh, axis=1, keepdims=True)
        cy, sy = np.cos(yaw), np.sin(yaw)
        a = np.stack(
            [
                cy * nh[:, 0] - sy * nh[:, 1],
                sy * nh[:, 0] + cy * nh[:, 1],
                np.zeros(batch),
            ],
            axis=1,
        )
        keep = x[:, 2] >= MIN_HEIGHT
        # the chord through x along a: exit point of the material entered at x
        eps = 1e-5
        t, _ = caster.cast(x + eps * a, a)
        keep &= np.isfinite(t) & (t + eps <= OPENING)
        t = np.where(keep, t, 0.0)
        c = x + 0.5 * (t + eps)[:, None] * a
        c, a = c[keep], a[keep]
        if len(c) == 0:
            continue
        ex = execute(caster, hmap, c, a)
        w = np.zeros(len(c))
        w[ex.live] = np.linalg.norm(ex.x2 - ex.x1, axis=1)
        antipodal = force_closure(ex, np.full(len(c), SAMPLING_FRICTION))
        sel = np.flatnonzero(antipodal)[: K - count]
        n = len(sel)
        center[count : count + n] = c[sel]
        axis[count : count + n] = a[sel]
        width[count : count + n] = w[sel]
        count += n
    valid = np.zeros(K, bool)
    valid[:count] = True
    return Reservoir(valid, center, axis, width, drawn)


def perturbations(
    rng: np.random.Generator, n: int, samples: int = SAMPLES
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Perturbations of n grasps: (dxy [n, S, 2], dyaw [n, S], mu [n, S]).

    Grasp i gets the i-th block of draws of each kind, so its perturbations do not
    depend on how many grasps come after it.
    """
    dxy = rng.normal(0.0, SIGMA_TRANSLATION, (n, samples, 2))
    dyaw = rng.normal(0.0, SIGMA_YAW, (n, samples))
    mu = np.clip(rng.normal(FRICTION_MEAN, FRICTION_SD, (n, samples)), 0.0, 1.0)
    return dxy, dyaw, mu


def robustness(
    caster: RayCaster,
    hmap: HeightMap,
    centers: np.ndarray,
    axes: np.ndarray,
    dxy: np.ndarray,
    dyaw: np.ndarray,
    mu: np.ndarray,
    progress=None,
) -> np.ndarray:
    """[N] fraction of the S perturbed executions of each grasp that end in force
    closure (perturbations from :func:`perturbations`, [N, S, ...]). Executions go
    to Embree in chunks of about ``_SAMPLE_CHUNK``; ``progress(fraction)`` is called
    after each chunk."""
    c = np.asarray(centers, np.float32)
    a = np.asarray(axes, np.float32)
    n, samples = dyaw.shape
    success = np.zeros((n, samples), bool)
    per = max(1, _SAMPLE_CHUNK // samples)
    for start in range(0, n, per):
        sl = slice(start, min(n, start + per))
        m = sl.stop - sl.start
        cc = np.repeat(c[sl], samples, axis=0)
        cc[:, :2] += dxy[sl].reshape(-1, 2)
        yaw = dyaw[sl].ravel()
        aa = np.repeat(a[sl], samples, axis=0)
        cy, sy = np.cos(yaw).astype(np.float32), np.sin(yaw).astype(np.float32)
        ax = np.empty_like(aa)
        ax[:, 0] = cy * aa[:, 0] - sy * aa[:, 1]
        ax[:, 1] = sy * aa[:, 0] + cy * aa[:, 1]
        ax[:, 2] = aa[:, 2]
        ex = execute(caster, hmap, cc, ax)
        success[sl] = force_closure(ex, mu[sl].ravel()).reshape(m, samples)
        if progress is not None:
            progress(sl.stop / n)
    return success.mean(axis=1)
