"""First-hit ray casting through Embree (the ``embreex`` bindings).

One :class:`RayCaster` holds the Embree scene of one mesh in one frame (metres); a
pose gets its own scene of the posed mesh (building one takes milliseconds). Rays
are cast in chunks of at most ``CHUNK`` rays; each chunk is a single Embree call.

Embree works in float32; objects are about 0.1 m, so a float32 position is good to
about 10 nm, far below any length that matters here.

Pad normals. A finger pad touches an area, not a point: pressed on a rough
surface, a flat pad rests on the plane of the surface under it, so the contact
normal it feels is that plane's (Dex-Net likewise takes its contact normals from
the gradient of a smoothed signed-distance field, BerkeleyAutomation/dex-net
``src/dexnet/grasping/contacts.py``). :func:`face_pad_normals` gives each face the
normal of the least-squares plane of the surface within a disc around it: the
area-weighted second moments of the faces whose centroids lie within the pad radius
of its centroid (each triangle with its own spread, so a single large face is
exact), counting only faces turned less than ``SAME_SIDE_DEG`` from it (the far side
of a thin wall or the other side of a sharp edge is not under the pad). On a flat
face this is the face's own normal; on a rough surface the facet-to-facet jumps
average out (tested on a sphere with 1 mm of vertex noise).

The plane is found with arithmetic that is exact IEEE on every processor (products,
sums in a fixed order, square roots; no LAPACK and no SIMD-dispatched reductions):
the smallest principal axis by power iteration on trace(C) I - C, started from the
area-weighted mean normal, which also orients it outwards.
"""

from __future__ import annotations

import numpy as np

from .errors import PrecomputeError

__all__ = ["CHUNK", "SAME_SIDE_DEG", "RayCaster", "face_pad_normals", "require_embree"]

CHUNK = 1 << 20
#: Faces turned more than this from a face do not count towards its pad normal.
SAME_SIDE_DEG = 80.0
# power iterations for the plane: the error shrinks at least by 1/2 per step
# (eigenvalues of trace(C) I - C of a disc patch: about r²/2, r²/4, r²/4)
_POWER_ITERATIONS = 40


def face_pad_normals(
    vertices: np.ndarray,
    faces: np.ndarray,
    radius: float,
    iterations: int = _POWER_ITERATIONS,
) -> np.ndarray:
    """[F, 3] unit pad normal of every face (see the module docstring): the normal
    of the area-weighted least-squares plane of the faces whose centroids lie
    within ``radius`` of its centroid and that are turned less than
    ``SAME_SIDE_DEG`` from it (itself included), oriented outwards."""
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    nf = len(f)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # 2 A n
    double_area = _norm(cross)
    unit = cross / np.maximum(double_area, 1e-300)[:, None]
    cen = (tri[:, 0] + tri[:, 1] + tri[:, 2]) / 3.0
    # second moment of each triangle about its centroid, per unit area
    e = tri - cen[:, None, :]
    own = np.empty((nf, 3, 3))
    for a in range(3):
        for b in range(3):
            own[:, a, b] = (
                e[:, 0, a] * e[:, 0, b]
                + e[:, 1, a] * e[:, 1, b]
                + e[:, 2, a] * e[:, 2, b]
            ) / 12.0
    if radius > 0 and nf > 1:
        pairs = cKDTree(cen).query_pairs(radius, output_type="ndarray")
    else:
        pairs = np.zeros((0, 2), np.int64)
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(nf)])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(nf)])
    cos = unit[i, 0] * unit[j, 0] + unit[i, 1] * unit[j, 1] + unit[i, 2] * unit[j, 2]
    keep = cos >= np.cos(np.deg2rad(SAME_SIDE_DEG))
    i, j = i[keep], j[keep]
    order = np.lexsort((j, i))  # a fixed summation order
    i, j = i[order], j[order]
    d = cen[j] - cen[i]
    w = 0.5 * double_area[j]
    m0 = np.bincount(i, w, nf)
    m1 = np.stack([np.bincount(i, w * d[:, a], nf) for a in range(3)], axis=1)
    mean = m1 / m0[:, None]
    shifted = np.empty((nf, 3, 3))  # trace(C) I - C, C the patch covariance
    for a in range(3):
        for b in range(a, 3):
            m2 = np.bincount(i, w * (d[:, a] * d[:, b] + own[j, a, b]), nf)
            shifted[:, a, b] = shifted[:, b, a] = -(m2 / m0 - mean[:, a] * mean[:, b])
    trace = -(shifted[:, 0, 0] + shifted[:, 1, 1] + shifted[:, 2, 2])
    for a in range(3):
        shifted[:, a, a] += trace
    start = np.stack(
        [np.bincount(i, w * unit[j, a], nf) for a in range(3)], axis=1
    )  # area-weighted mean normal
    start /= np.maximum(_norm(start), 1e-300)[:, None]
    x = start
    for _ in range(iterations):
        y = (
            shifted[:, :, 0] * x[:, 0:1]
            + shifted[:, :, 1] * x[:, 1:2]
            + shifted[:, :, 2] * x[:, 2:3]
        )
        x = y / np.maximum(_norm(y), 1e-300)[:, None]
    side = x[:, 0] * start[:, 0] + x[:, 1] * start[:, 1] + x[:, 2] * start[:, 2]
    return np.where((side < 0)[:, None], -x, x)


def _norm(x: np.ndarray) -> np.ndarray:
    """[N] Euclidean length of the rows of x [N, 3], in a fixed order."""
    return np.sqrt(x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1] + x[:, 2] * x[:, 2])


def require_embree():
    """The ``embreex`` scene module, or a clear error when it is missing."""
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as e:  # pragma: no cover - embreex is a dependency
        raise PrecomputeError(
            f"Embree ray casting is not available (cannot import embreex: {e}); "
            "install it with: pip install embreex"
        ) from None
    return rtcore_scene, TriangleMesh


class RayCaster:
    """First hits of rays against one mesh."""

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        pad_normals: dict[float, np.ndarray] | None = None,
    ):
        """``pad_normals``: {radius: [F, 3]} already known (for example those of
        the unposed mesh, rotated into this frame); others are computed on first
        use."""
        rtcore_scene, TriangleMesh = require_embree()
        self.vertices = np.asarray(vertices, np.float64)
        self.faces = np.asarray(faces, np.int64)
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.face_normals = n / np.linalg.norm(n, axis=1, keepdims=True)
        # one extra zero row: the "normal" of a miss
        self._normals = np.concatenate([self.face_normals, np.zeros((1, 3))])
        self._normals32 = self._normals.astype(np.float32)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(
            self._scene,
            np.ascontiguousarray(self.vertices, np.float32),
            np.ascontiguousarray(self.faces, np.int32),
        )
        self.rays_cast = 0
        self._pad: dict[float, np.ndarray] = {}
        for radius, nrm in (pad_normals or {}).items():
            self._set_pad(radius, nrm)

    def _set_pad(self, radius: float, normals: np.ndarray) -> np.ndarray:
        nrm = np.asarray(normals, np.float32).reshape(len(self.faces), 3)
        table = np.concatenate([nrm, np.zeros((1, 3), np.float32)])
        self._pad[float(radius)] = table
        return table

    def pad_normals_of(self, prim: np.ndarray, radius: float) -> np.ndarray:
        """[..., 3] float32 pad normals (:func:`face_pad_normals`, disc of
        ``radius``) of faces ``prim`` (zeros where -1)."""
        table = self._pad.get(float(radius))
        if table is None:
            table = self._set_pad(
                radius, face_pad_normals(self.vertices, self.faces, radius)
            )
        return table[np.where(prim >= 0, prim, len(self.faces))]

    def cast(
        self, origins: np.ndarray, directions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """First hit of each ray (origins, directions [N, 3], in the mesh's frame;
        directions need not be unit length: distances are in units of their length).

        Returns (t [N] float64: distance along the ray, inf for a miss;
        normal [N, 3] float64: outward unit normal of the hit face, zeros for a miss).
        """
        t, prim = self.cast_raw(origins, directions)
        return t.astype(np.float64), self.normals_of(prim)

    def cast_raw(
        self, origins: np.ndarray, directions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(t [N] float32, inf for a miss; face index [N] int32, -1 for a miss)."""
        o = np.asarray(origins).reshape(-1, 3)
        d = np.asarray(directions).reshape(-1, 3)
        n = len(o)
        t = np.empty(n, np.float32)
        prim = np.empty(n, np.int32)
        for start in range(0, n, CHUNK):
            sl = slice(start, min(n, start + CHUNK))
            res = self._scene.run(
                np.ascontiguousarray(o[sl], np.float32),
                np.ascontiguousarray(d[sl], np.float32),
                output=1,
            )
            prim[sl] = res["primID"]
            t[sl] = res["tfar"]
        self.rays_cast += n
        t[prim < 0] = np.inf
        return t, prim

    def normals_of(self, prim: np.ndarray, dtype=np.float64) -> np.ndarray:
        """[..., 3] outward unit normals of faces ``prim`` (zeros where -1)."""
        table = self._normals32 if dtype == np.float32 else self._normals
        return table[np.where(prim >= 0, prim, len(self.faces))]
