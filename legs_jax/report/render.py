"""Small ray-traced pictures of an object in a stable pose, with grasps on top.

An orthographic camera looks at the object from above at an angle; every pixel's
ray is cast against the mesh (trimesh's ray interface; Embree when available) and
against the table plane under the object. Faces are lit two-sided with a Lambert
term, the table gets the object's shadow. The result is an RGBA image plus a
projection that maps 3-D points to pixel coordinates and tells which of them are
hidden, so that grasps can be drawn over the picture with matplotlib.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

__all__ = [
    "Rendering",
    "choose_scale",
    "grasp_segments",
    "load_mesh",
    "pose_vertices",
    "problem_scale",
    "render",
]

_OBJECT_RGB = np.array([0.55, 0.62, 0.72])
_TABLE_RGB = np.array([0.93, 0.93, 0.91])


@dataclasses.dataclass(frozen=True)
class Rendering:
    """An RGBA picture [S, S, 4] and the camera that made it."""

    image: np.ndarray  # [S, S, 4] float in [0, 1], row 0 at the top
    origin: np.ndarray  # [3] centre of the image plane (world)
    right: np.ndarray  # [3] unit vector along image columns
    up: np.ndarray  # [3] unit vector along image rows (upwards)
    view: np.ndarray  # [3] unit viewing direction
    half: float  # half width of the image plane (world units)
    depth: np.ndarray  # [S, S] distance along the view of the first hit (inf: none)

    @property
    def size(self) -> int:
        return int(self.image.shape[0])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ([N, 2]: column, row) of world points [N, 3], and
        whether each point is visible (not behind the surface)."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        rel = points - self.origin
        x = rel @ self.right
        y = rel @ self.up
        z = rel @ self.view
        S = self.size
        col = (x / self.half + 1.0) * 0.5 * S - 0.5
        row = (1.0 - y / self.half) * 0.5 * S - 0.5
        ci = np.clip(np.round(col).astype(int), 0, S - 1)
        ri = np.clip(np.round(row).astype(int), 0, S - 1)
        surface = self.depth[ri, ci]
        visible = z <= surface + 0.02 * self.half
        return np.stack([col, row], axis=1), visible


def load_mesh(path):
    """The mesh at ``path`` as one ``trimesh.Trimesh`` (scenes are merged)."""
    import trimesh

    mesh = trimesh.load(str(path), force="mesh", process=False)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: no triangles")
    return mesh


def pose_vertices(
    vertices: np.ndarray,
    transform: np.ndarray | None,
    scale: float = 1.0,
) -> np.ndarray:
    """Vertices [V, 3] scaled by ``scale`` and moved by the 4x4 ``transform``."""
    v = np.asarray(vertices, np.float64) * scale
    if transform is None:
        return v
    tf = np.asarray(transform, np.float64)
    return v @ tf[:3, :3].T + tf[:3, 3]


def _basis(elevation: float, azimuth: float) -> tuple[np.ndarray, ...]:
    el, az = np.deg2rad(elevation), np.deg2rad(azimuth)
    # Direction from the camera towards the scene.
    view = -np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.cross(view, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, view)
    return view, right, up


def render(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    size: int = 360,
    elevation: float = 35.0,
    azimuth: float = -60.0,
    floor: bool = True,
    margin: float = 1.15,
) -> Rendering:
    """Ray-trace the mesh (world coordinates, z up, table under its lowest point).

    Args:
      vertices: [V, 3] vertex positions; faces: [F, 3] triangle indices.
      size: image side in pixels.
      elevation, azimuth: camera direction in degrees.
      floor: draw the table plane with the object's shadow.
      margin: image half width over the object's bounding radius.
    """
    import trimesh

    vertices = np.asarray(vertices, np.float64)
    mesh = trimesh.Trimesh(vertices, np.asarray(faces), process=False)
    view, right, up = _basis(elevation, azimuth)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo)) or 1.0
    half = margin * radius
    # The object's middle sits in the middle of the picture; the camera plane is
    # far enough in front that every ray starts outside the scene.
    origin = centre - view * 4.0 * radius
    S = int(size)
    grid = (np.arange(S) + 0.5) / S * 2.0 - 1.0
    xs, ys = np.meshgrid(grid * half, -grid * half)
    starts = origin + xs.reshape(-1, 1) * right + ys.reshape(-1, 1) * up
    dirs = np.broadcast_to(view, starts.shape).copy()

    tri, ray, loc = mesh.ray.intersects_id(
        starts, dirs, multiple_hits=False, return_locations=True
    )
    n_pix = S * S
    depth = np.full(n_pix, np.inf)
    depth[ray] = (loc - origin) @ view
    rgb = np.ones((n_pix, 3))
    alpha = np.zeros(n_pix)

    light = -view + np.array([0.3, -0.2, 1.2])
    light /= np.linalg.norm(light)
    normals = mesh.face_normals[tri]
    flip = (normals @ view) > 0  # two-sided: face the camera
    normals[flip] *= -1.0
    lambert = np.clip(normals @ light, 0.0, 1.0)
    shade = 0.35 + 0.65 * lambert
    rgb[ray] = _OBJECT_RGB * shade[:, None]
    alpha[ray] = 1.0

    if floor:
        z0 = lo[2]
        miss = np.setdiff1d(np.arange(n_pix), ray)
        if abs(view[2]) > 1e-6:
            t = (z0 - starts[miss, 2]) / view[2]
            pts = starts[miss] + t[:, None] * view
            d = np.linalg.norm(pts[:, :2] - centre[:2], axis=1)
            on = (t > 0) & (d < 1.3 * radius)
            idx, pts, d = miss[on], pts[on], d[on]
            shadow = np.zeros(len(idx), bool)
            if len(idx):
                lit = mesh.ray.intersects_any(
                    pts + light * 1e-6 * radius, np.broadcast_to(light, pts.shape)
                )
                shadow = np.asarray(lit, bool)
            fade = np.clip((1.3 * radius - d) / (0.5 * radius), 0.0, 1.0)
            tone = np.where(shadow, 0.72, 1.0)
            rgb[idx] = _TABLE_RGB * tone[:, None]
            alpha[idx] = fade
    image = np.concatenate([rgb, alpha[:, None]], axis=1).reshape(S, S, 4)
    return Rendering(
        image=np.clip(image, 0.0, 1.0),
        origin=origin + view * 4.0 * radius,
        right=right,
        up=up,
        view=view,
        half=half,
        depth=(depth - 4.0 * radius).reshape(S, S),
    )


def grasp_segments(
    center: np.ndarray, axis: np.ndarray, width: np.ndarray, opening: float = 1.0
) -> np.ndarray:
    """Jaw-to-jaw segments [N, 2, 3] of parallel-jaw grasps (centre, unit axis,
    width; ``opening`` scales the width)."""
    center = np.asarray(center, np.float64).reshape(-1, 3)
    axis = np.asarray(axis, np.float64).reshape(-1, 3)
    half = 0.5 * opening * np.asarray(width, np.float64).reshape(-1, 1)
    return np.stack([center - half * axis, center + half * axis], axis=1)


def problem_scale(pb, vertices, transform, centers) -> float:
    """The factor from the mesh file's units to the problem's metres: the one its
    build recorded (``meta["mesh_scale"]``, the size rule included), else a guess
    from the grasp centres (:func:`choose_scale`)."""
    recorded = (pb.meta or {}).get("mesh_scale") if pb is not None else None
    if isinstance(recorded, int | float) and recorded > 0:
        return float(recorded)
    return choose_scale(vertices, transform, centers)


def choose_scale(
    vertices: np.ndarray,
    transform: np.ndarray | None,
    centers: np.ndarray,
    candidates: Sequence[float] = (1.0, 1e-3, 1e-2, 1e3),
) -> float:
    """The mesh scale under which the grasp centres fit the posed mesh best (meshes
    in millimetres, grasps in metres): most centres inside the mesh's bounding box,
    and the centres' spread of the same order as the mesh; 1 without centres."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    if len(centers) == 0:
        return 1.0
    spread = float((centers.max(axis=0) - centers.min(axis=0)).max())
    best, best_score = 1.0, -np.inf
    for c in candidates:
        v = pose_vertices(vertices, transform, c)
        lo, hi = v.min(axis=0), v.max(axis=0)
        extent = float((hi - lo).max())
        pad = 0.1 * extent
        inside = np.all((centers >= lo - pad) & (centers <= hi + pad), axis=1)
        score = float(inside.mean())
        if spread > 0 and extent > 0:
            score -= 0.1 * abs(np.log10(spread / extent))
        if score > best_score + 1e-9:
            best, best_score = c, score
    return best
