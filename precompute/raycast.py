"""First-hit ray casting through Embree (the ``embreex`` bindings).

One :class:`RayCaster` holds the Embree scene of one mesh in one frame (metres); a
pose gets its own scene of the posed mesh (building one takes milliseconds). Rays
are cast in chunks of at most ``CHUNK`` rays; each chunk is a single Embree call.

Embree works in float32; objects are about 0.1 m, so a float32 position is good to
about 10 nm, far below any length that matters here.
"""

from __future__ import annotations

import numpy as np

from .errors import PrecomputeError

__all__ = ["CHUNK", "RayCaster", "require_embree"]

CHUNK = 1 << 20


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

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
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
