"""Stable poses, landing probabilities and the topple matrix.

Quasi-static convex-hull model (Goldberg et al. 1999, "Part pose statistics"; the
model behind ``trimesh.poses.compute_stable_poses``), vectorised over hull triangles:

- A dropped object first touches the table with the hull triangle pierced by the
  gravity ray from its centre of mass; for a uniformly random orientation that is
  triangle f with probability Ω_f / 4π, Ω_f the solid angle of f about the centre of
  mass (Van Oosterom-Strackee formula).
- Resting on f, the object is stable when the centre of mass projects inside f (all
  barycentric coordinates ≥ -1e-9). Otherwise it rolls over the edge that the ray from
  f's centroid to the projection crosses (the edge opposite the vertex with the
  smallest barycentric coordinate) onto the neighbouring triangle; every roll lowers
  the centre of mass, so following these links ("hull descent") ends in a stable
  triangle, its sink. Coplanar sink triangles form one resting facet.
- Landing probability of a facet: the total Ω of the triangles whose sink lies in it.

Equivalent poses are merged: two facets whose rested shapes coincide up to a rotation
about the vertical axis (the symmetric faces of a box, the sides of a turned part) are
one pose, as an overhead camera cannot tell them apart. The test compares dense
surface samples of the two rested shapes at the best of 720 yaw angles: they are the
same pose when 95% of the points lie within 1% of the object's size of the other
shape. Then poses with λ below ``threshold`` (default 0.01) are dropped and λ is
renormalised. Poses are sorted by λ, largest first.

Topple matrix (after a failed grasp): the object in pose s is tilted about a
horizontal axis and left to settle by hull descent from the triangle the tilted
gravity ray pierces. Tilts: a deterministic grid of 12 tilt angles (quantiles of a
half-normal with σ = 15°, so from 1° to 34°) × 24 azimuths = 288 samples per pose.
Samples that settle in a dropped pose are left out and the row is renormalised.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = [
    "TILT_SIGMA_DEG",
    "LANDING_THRESHOLD",
    "Hull",
    "StablePoses",
    "hull_model",
    "stable_poses",
    "topple_matrix",
    "pose_frame",
]

TILT_SIGMA_DEG = 15.0
TILT_ANGLES = 12
TILT_AZIMUTHS = 24
LANDING_THRESHOLD = 0.01
_STABLE_TOL = 1e-9
_MERGE_TOL = 0.01  # fraction of the object's longest side
_MERGE_QUANTILE = 0.95


@dataclasses.dataclass(frozen=True, eq=False)
class Hull:
    """The convex hull and its topple graph, in the mesh frame (metres)."""

    com: np.ndarray  # [3] centre of mass
    vertices: np.ndarray  # [Vh, 3]
    faces: np.ndarray  # [Fh, 3]
    normals: np.ndarray  # [Fh, 3] outward unit normals
    offsets: np.ndarray  # [Fh] distance from the centre of mass to each face plane
    solid_angle: np.ndarray  # [Fh] Ω_f, sums to 4π
    successor: np.ndarray  # [Fh] next triangle when rolling (itself if stable)
    sink: np.ndarray  # [Fh] stable triangle reached by hull descent
    facet: np.ndarray  # [Fh] coplanar facet id of each triangle


@dataclasses.dataclass(frozen=True, eq=False)
class StablePoses:
    """The retained poses of an object, sorted by landing probability."""

    landing: np.ndarray  # [P] λ, sums to 1
    transforms: np.ndarray  # [P, 4, 4] mesh frame -> pose frame (rigid, metres)
    normals: np.ndarray  # [P, 3] outward normal (mesh frame) of the resting facet
    members: tuple[tuple[int, ...], ...]  # [P] facet ids merged into each pose
    facet_pose: np.ndarray  # [num facets] retained pose of each facet, -1 if none
    dropped_mass: float  # λ of the dropped poses before renormalisation
    num_candidates: int  # stable facets before merging


def _solid_angles(tri: np.ndarray, com: np.ndarray) -> np.ndarray:
    a, b, c = (tri[:, i] - com for i in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    num = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    den = (
        la * lb * lc
        + np.einsum("ij,ij->i", a, b) * lc
        + np.einsum("ij,ij->i", a, c) * lb
        + np.einsum("ij,ij->i", b, c) * la
    )
    return 2.0 * np.arctan2(num, den)


def _barycentric(tri: np.ndarray, pts: np.ndarray) -> np.ndarray:
    v0 = tri[:, 1] - tri[:, 0]
    v1 = tri[:, 2] - tri[:, 0]
    v2 = pts - tri[:, 0]
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - v - w, v, w], axis=1)


def _neighbours(faces: np.ndarray) -> np.ndarray:
    """[F, 3] the triangle across the edge opposite vertex j of each triangle."""
    f = len(faces)
    # edge opposite vertex j is (v[j+1], v[j+2])
    e = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1)
    e = np.sort(e.reshape(-1, 2), axis=1)
    key = e[:, 0].astype(np.int64) * (faces.max() + 1) + e[:, 1]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    if len(ks) % 2 or not np.all(ks[0::2] == ks[1::2]):
        raise ValueError("convex hull is not a closed 2-manifold")
    a, b = order[0::2], order[1::2]
    nb = np.empty(3 * f, np.int64)
    nb[a] = b // 3
    nb[b] = a // 3
    return nb.reshape(f, 3)


def hull_model(vertices: np.ndarray, faces: np.ndarray, com: np.ndarray) -> Hull:
    """Convex hull of the mesh and its topple graph about ``com``."""
    import trimesh

    hull = trimesh.Trimesh(vertices, faces, process=False).convex_hull
    hv = np.asarray(hull.vertices, np.float64)
    hf = np.asarray(hull.faces, np.int64)
    tri = hv[hf]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = np.einsum("ij,ij->i", normals, tri[:, 0] - com)
    if offsets.min() <= 0:
        raise ValueError("centre of mass is not strictly inside the convex hull")
    omega = _solid_angles(tri, com)
    proj = com + offsets[:, None] * normals
    bary = _barycentric(tri, proj)
    nb = _neighbours(hf)
    j = np.argmin(bary, axis=1)
    stable = bary[np.arange(len(hf)), j] >= -_STABLE_TOL
    succ = np.where(stable, np.arange(len(hf)), nb[np.arange(len(hf)), j])
    sink = succ.copy()
    for _ in range(64):  # pointer doubling: 2**64 steps
        nxt = sink[sink]
        if np.array_equal(nxt, sink):
            break
        sink = nxt
    sink = _break_cycles(sink, succ, offsets)
    facet = np.arange(len(hf))
    for k, group in enumerate(hull.facets):
        facet[group] = len(hf) + k
    _, facet = np.unique(facet, return_inverse=True)
    return Hull(com, hv, hf, normals, offsets, omega, succ, sink, facet)


def _break_cycles(sink, succ, offsets):
    """Paths stuck in a cycle (only possible through round-off on coplanar
    triangles) end at the cycle's triangle closest to the centre of mass."""
    bad = np.flatnonzero(succ[sink] != sink)
    for i in bad:
        cycle = [int(sink[i])]
        while int(succ[cycle[-1]]) != cycle[0] and len(cycle) <= len(succ):
            cycle.append(int(succ[cycle[-1]]))
        end = min(cycle, key=lambda t: (offsets[t], t))
        succ[end] = end
    if bad.size:
        sink = succ.copy()
        for _ in range(64):
            nxt = sink[sink]
            if np.array_equal(nxt, sink):
                break
            sink = nxt
    return sink


def pose_frame(
    normal: np.ndarray, vertices: np.ndarray, com: np.ndarray, second: np.ndarray
) -> np.ndarray:
    """[4, 4] rigid transform putting the facet with outward ``normal`` on the table
    (z = 0, z up), the centre of mass above the origin. The yaw is canonical: the
    pose's x axis is the horizontal principal axis of largest spread of the solid
    (``second``: its [3, 3] second-moment matrix about the centre of mass), signed
    towards the farther hull vertex."""
    z = -np.asarray(normal, np.float64)
    z /= np.linalg.norm(z)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    basis = np.stack([x, y])
    _, vec = np.linalg.eigh(basis @ second @ basis.T)
    major = vec[:, 1]
    proj = (vertices - com) @ (basis.T @ major)
    if abs(proj.max()) < abs(proj.min()):
        major = -major
    ax = basis.T @ major
    ay = np.cross(z, ax)
    rot = np.stack([ax, ay, z])
    tf = np.eye(4)
    tf[:3, :3] = rot
    tf[:2, 3] = -(rot @ com)[:2]
    tf[2, 3] = -float((vertices @ rot[2]).min())
    return tf


def second_moment(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[3, 3] ∫ r rᵀ dV about the centre of mass (unit density)."""
    import trimesh

    inertia = np.asarray(
        trimesh.Trimesh(vertices, faces, process=False).moment_inertia, np.float64
    )
    return 0.5 * np.trace(inertia) * np.eye(3) - inertia


def stable_poses(
    hull: Hull,
    vertices: np.ndarray,
    faces: np.ndarray,
    threshold: float = LANDING_THRESHOLD,
    merge: bool = True,
) -> StablePoses:
    """Stable poses of the mesh with its hull model: merge equivalent ones, drop
    those under ``threshold``, renormalise, sort by λ (ties: facet id)."""
    num_facets = int(hull.facet.max()) + 1
    mass = np.bincount(
        hull.facet[hull.sink], weights=hull.solid_angle, minlength=num_facets
    ) / (4.0 * np.pi)
    cands = np.flatnonzero(mass > 0)
    # facet normal: area-weighted mean of its triangles' normals
    tri = hull.vertices[hull.faces]
    area = 0.5 * np.linalg.norm(
        np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1
    )
    fn = np.zeros((num_facets, 3))
    np.add.at(fn, hull.facet, hull.normals * area[:, None])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    second = second_moment(vertices, faces)
    frames = {int(f): pose_frame(fn[f], hull.vertices, hull.com, second) for f in cands}

    groups = [[int(f)] for f in cands]
    if merge and len(cands) > 1:
        groups = _merge_equivalent(cands, mass, frames, vertices, faces, second)
    g_mass = np.array([mass[g].sum() for g in groups])
    order = sorted(range(len(groups)), key=lambda i: (-g_mass[i], min(groups[i])))
    keep = [i for i in order if g_mass[i] >= threshold]
    if not keep:  # every pose is tiny: keep the most likely one
        keep = order[:1]
    total = g_mass[keep].sum()
    facet_pose = np.full(num_facets, -1, np.int64)
    reps, members = [], []
    for p, i in enumerate(keep):
        g = groups[i]
        rep = max(g, key=lambda f: (mass[f], -f))
        reps.append(rep)
        members.append(tuple(sorted(g)))
        facet_pose[g] = p
    return StablePoses(
        landing=g_mass[keep] / total,
        transforms=np.stack([frames[r] for r in reps]),
        normals=fn[reps],
        members=tuple(members),
        facet_pose=facet_pose,
        dropped_mass=float(1.0 - total),
        num_candidates=len(cands),
    )


def _merge_equivalent(cands, mass, frames, vertices, faces, second):
    """Union of stable facets whose rested shapes coincide up to a yaw rotation.

    Prefilter (exact, cheap): the height of the centre of mass and the yaw
    invariants of the solid's second-moment matrix in the pose frame must agree.
    Then the yaw that could align the two shapes: their horizontal principal axes
    (two candidates, ±, refined ±2°) when those are well defined, else a search over
    720 yaws. Test: 95% of 1500 surface points of one shape, yawed onto the other
    and mapped back into the mesh frame, lie within tol of the surface."""
    import trimesh
    from scipy.spatial import cKDTree

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    size = float(np.ptp(vertices, axis=0).max())
    tol = _MERGE_TOL * size
    scale2 = float(np.trace(second))
    inv = {}
    for f in cands:
        tf = frames[int(f)]
        m = tf[:3, :3] @ second @ tf[:3, :3].T
        ev = np.linalg.eigvalsh(m[:2, :2])
        inv[int(f)] = np.array([m[2, 2], ev[0], ev[1], np.hypot(m[0, 2], m[1, 2])])
    surface = None
    pts_query = _surface_points(mesh, 1500, seed=2)
    parent = {int(f): int(f) for f in cands}

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    def distances(q, b, angles):
        """[A, N] distance to the surface of points q (pose frame of a), yawed by
        ``angles`` and mapped back into the mesh frame through pose b."""
        ib = np.linalg.inv(frames[b])
        cs, sn = np.cos(angles)[:, None], np.sin(angles)[:, None]
        x = q[:, 0][None] * cs - q[:, 1][None] * sn
        y = q[:, 0][None] * sn + q[:, 1][None] * cs
        z = np.broadcast_to(q[:, 2], x.shape)
        pts = np.stack([x, y, z], -1) @ ib[:3, :3].T + ib[:3, 3]
        d, _ = surface.query(pts.reshape(-1, 3), distance_upper_bound=2 * tol)
        d = np.where(np.isfinite(d), d, 4 * tol)  # beyond the bound: far
        return d.reshape(len(angles), -1)

    full = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    fine = np.deg2rad(np.arange(-2.0, 2.01, 0.5))
    ordered = sorted((int(f) for f in cands), key=lambda f: (-mass[f], f))
    for i, a in enumerate(ordered):
        qa = None
        for b in ordered[i + 1 :]:
            if find(a) == find(b):
                continue
            if abs(frames[a][2, 3] - frames[b][2, 3]) > tol:
                continue
            if np.abs(inv[a] - inv[b]).max() > 0.02 * scale2:
                continue
            if surface is None:
                n_dense = int(np.clip(mesh.area / (0.5 * tol) ** 2, 20000, 100000))
                surface = cKDTree(
                    np.concatenate([_surface_points(mesh, n_dense, 1), vertices])
                )
            if qa is None:
                tf = frames[a]
                qa = pts_query @ tf[:3, :3].T + tf[:3, 3]
            ev = inv[a][1:3]
            if ev[1] - ev[0] > 0.05 * (ev[0] + ev[1]):
                # both frames put x on the major axis: the yaw is 0 or π
                cands_yaw = np.concatenate([fine, np.pi + fine])
            else:
                coarse = distances(qa[::25], b, full)
                score = np.quantile(coarse, _MERGE_QUANTILE, axis=1)
                best = full[np.argsort(score, kind="stable")[:3]]
                cands_yaw = (best[:, None] + fine[None, :]).ravel()
            # a subsample first: most pairs fail there
            d = distances(qa[::10], b, cands_yaw)
            ok = np.quantile(d, _MERGE_QUANTILE, axis=1) <= 1.5 * tol
            if not ok.any():
                continue
            d = distances(qa, b, cands_yaw[ok])
            if np.quantile(d, _MERGE_QUANTILE, axis=1).min() <= tol:
                parent[find(b)] = find(a)
    groups: dict[int, list[int]] = {}
    for f in ordered:
        groups.setdefault(find(f), []).append(f)
    return list(groups.values())


def _surface_points(mesh, n: int, seed: int) -> np.ndarray:
    """Deterministic area-weighted surface samples (mesh frame)."""
    rng = np.random.default_rng(seed)
    tri = mesh.triangles
    area = mesh.area_faces
    idx = rng.choice(len(tri), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    return np.einsum("ij,ijk->ik", w, tri[idx])


def tilt_directions(normal: np.ndarray) -> np.ndarray:
    """[N, 3] gravity directions (mesh frame) of the tilt samples about a pose whose
    resting facet has outward ``normal``."""
    from scipy.stats import norm

    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    q = (np.arange(TILT_ANGLES) + 0.5) / TILT_ANGLES
    theta = np.deg2rad(TILT_SIGMA_DEG) * norm.ppf(0.5 + 0.5 * q)  # half-normal
    phi = 2 * np.pi * (np.arange(TILT_AZIMUTHS) + 0.5) / TILT_AZIMUTHS
    # stagger the azimuths of successive rings
    phi = phi[None, :] + (np.pi / TILT_AZIMUTHS) * (np.arange(TILT_ANGLES) % 2)[:, None]
    th = np.broadcast_to(theta[:, None], phi.shape)
    d = np.cos(th)[..., None] * n + np.sin(th)[..., None] * (
        np.cos(phi)[..., None] * e1 + np.sin(phi)[..., None] * e2
    )
    return d.reshape(-1, 3)


def settle(hull: Hull, gravity: np.ndarray) -> np.ndarray:
    """[N] facet the object settles on for gravity directions [N, 3] (mesh frame):
    the hull triangle pierced by the gravity ray from the centre of mass, then hull
    descent to its sink."""
    g = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    cos = g @ hull.normals.T  # [N, Fh]
    with np.errstate(divide="ignore"):
        t = np.where(cos > 1e-12, hull.offsets[None, :] / cos, np.inf)
    tri = np.argmin(t, axis=1)
    return hull.facet[hull.sink[tri]]


def topple_matrix(hull: Hull, poses: StablePoses) -> np.ndarray:
    """[P, P] row s: distribution of the next pose after a failed grasp in s."""
    P = len(poses.landing)
    out = np.zeros((P, P))
    for s in range(P):
        facets = settle(hull, tilt_directions(poses.normals[s]))
        dest = poses.facet_pose[facets]
        dest = dest[dest >= 0]
        if dest.size == 0:  # cannot happen for small tilts; stay put to be safe
            out[s, s] = 1.0
            continue
        out[s] = np.bincount(dest, minlength=P) / dest.size
    return out
