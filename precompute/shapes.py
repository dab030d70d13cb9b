"""Generated training objects for the learned prior, never the 62.

Three families in turn (object ``index`` is of family ``index % 3``), each draw
from its own seeded stream ``SeedSequence([seed, STREAM_SHAPES, index, attempt])``:

- ``csg``: a random primitive (box, cylinder or cone, sphere, torus, extruded
  star polygon) joined with one to three more by union (70 %) or difference
  (30 %), each randomly turned and shifted (manifold3d booleans);
- ``hull``: the convex hull of 6-40 points of an anisotropic Gaussian cloud;
- ``blob``: a smooth star-shaped body, an icosphere (642 vertices) whose radius
  is exp(Σ a_k cos(w_k·d + φ_k)) over four random low-frequency waves, stretched
  along its axes.

A draw is kept when manifold3d accepts it as one closed solid (one piece, a
volume of at least 15 % of its bounding box's) and trimesh finds it watertight;
otherwise the next ``attempt`` is drawn. Then it is sized by EGAD!'s rule for the
gripper (:func:`precompute.mesh.egad_factor` with the 80 mm opening: the largest
side of the oriented bounding box becomes 80 mm, the smallest is at most 64 mm),
as the EGAD! evaluation meshes are. Nothing here reads the evaluation meshes.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .errors import PrecomputeError
from .grasps import OPENING
from .mesh import egad_factor

__all__ = ["KINDS", "STREAM_SHAPES", "Shape", "generate", "generate_many"]

KINDS = ("csg", "hull", "blob")
STREAM_SHAPES = 11  # seed-sequence tag of the shape stream
_MAX_ATTEMPTS = 50
_MIN_FILL = 0.15  # volume / bounding-box volume below this is refused
_SEGMENTS = 32  # circular segments of round primitives


@dataclasses.dataclass(frozen=True, eq=False)
class Shape:
    """A generated, watertight, outward-oriented object in metres."""

    index: int
    kind: str
    vertices: np.ndarray  # [V, 3] float64, metres
    faces: np.ndarray  # [F, 3] int64
    scale: float  # the EGAD! factor applied to the raw draw

    def trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def _rng(seed: int, index: int, attempt: int) -> np.random.Generator:
    ss = np.random.SeedSequence([seed, STREAM_SHAPES, index, attempt])
    return np.random.Generator(np.random.PCG64(ss))


def _primitive(rng: np.random.Generator):
    import manifold3d as m3

    kind = rng.integers(5)
    if kind == 0:
        size = rng.uniform(0.3, 1.0, 3)
        body = m3.Manifold.cube(tuple(size), center=True)
    elif kind == 1:
        r = rng.uniform(0.15, 0.5)
        r2 = r * (rng.uniform(0.0, 1.0) if rng.random() < 0.3 else 1.0)
        body = m3.Manifold.cylinder(rng.uniform(0.3, 1.0), r, r2, _SEGMENTS, True)
    elif kind == 2:
        body = m3.Manifold.sphere(rng.uniform(0.2, 0.5), _SEGMENTS)
    elif kind == 3:
        big = rng.uniform(0.25, 0.45)
        small = rng.uniform(0.06, 0.4) * big
        ring = m3.CrossSection.circle(small, 16).translate((big, 0.0))
        body = ring.revolve(_SEGMENTS)
    else:
        n = int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = rng.uniform(0.2, 0.5, n)
        pts = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
        section = m3.CrossSection([pts.tolist()])
        body = section.extrude(rng.uniform(0.1, 0.8)).translate((0, 0, -0.2))
    angles = rng.uniform(-180.0, 180.0, 3)
    shift = rng.normal(0.0, 0.2, 3)
    return body.rotate(tuple(angles)).translate(tuple(shift))


def _csg(rng: np.random.Generator):
    body = _primitive(rng)
    for _ in range(int(rng.integers(1, 4))):
        other = _primitive(rng)
        body = body - other if rng.random() < 0.3 else body + other
    return body


def _hull(rng: np.random.Generator):
    import manifold3d as m3

    n = int(rng.integers(6, 41))
    pts = rng.normal(0.0, 1.0, (n, 3)) * rng.uniform(0.2, 1.0, 3)
    return m3.Manifold.hull_points(pts.tolist())


def _blob(rng: np.random.Generator):
    import manifold3d as m3
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    d = np.asarray(sphere.vertices, np.float64)
    log_r = np.zeros(len(d))
    for _ in range(4):
        w = rng.normal(0.0, 1.5, 3)
        log_r += rng.uniform(0.05, 0.3) * np.cos(d @ w + rng.uniform(0, 2 * np.pi))
    v = d * np.exp(log_r)[:, None] * rng.uniform(0.4, 1.0, 3)
    mesh = m3.Mesh(
        vert_properties=np.asarray(v, np.float32),
        tri_verts=np.asarray(sphere.faces, np.uint32),
    )
    return m3.Manifold(mesh)


_MAKERS = {"csg": _csg, "hull": _hull, "blob": _blob}


def _accept(body):
    """(vertices, faces) of a draw that is one closed solid, else None."""
    import manifold3d as m3
    import trimesh

    if body.is_empty() or body.status() != m3.Error.NoError:
        return None
    if len(body.decompose()) != 1:
        return None
    out = body.to_mesh()
    mesh = trimesh.Trimesh(
        np.asarray(out.vert_properties, np.float64)[:, :3],
        np.asarray(out.tri_verts, np.int64),
    )
    if not mesh.is_watertight or mesh.volume <= 0:
        return None
    box = np.prod(np.ptp(mesh.vertices, axis=0))
    if mesh.volume < _MIN_FILL * box:
        return None
    return mesh


def generate(index: int, seed: int = 0) -> Shape:
    """Object ``index`` of the generated set ``seed`` (see the module docstring)."""
    import trimesh

    if index < 0 or seed < 0:
        raise PrecomputeError(f"shape index and seed must be non-negative ({index})")
    kind = KINDS[index % len(KINDS)]
    for attempt in range(_MAX_ATTEMPTS):
        mesh = _accept(_MAKERS[kind](_rng(seed, index, attempt)))
        if mesh is None:
            continue
        faces = np.asarray(mesh.faces, np.int64)
        v = mesh.vertices - mesh.center_mass
        # the oriented box of the centred solid (ties between equal-volume boxes
        # are broken the same way before and after scaling)
        _, extents = trimesh.bounds.oriented_bounds(
            trimesh.Trimesh(v, faces, process=False)
        )
        factor = egad_factor(extents, OPENING)
        return Shape(index, kind, v * factor, faces, factor)
    raise PrecomputeError(  # pragma: no cover - never seen in practice
        f"generated shape {index} (seed {seed}): no closed solid in "
        f"{_MAX_ATTEMPTS} attempts"
    )


def generate_many(count: int, seed: int = 0) -> list[Shape]:
    """Objects 0 .. count-1 of the generated set ``seed``."""
    return [generate(i, seed) for i in range(count)]
