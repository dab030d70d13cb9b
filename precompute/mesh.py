"""Loading a mesh in metres, repairing what can be repaired, refusing the rest.

Units. Every length inside precompute is in metres. A mesh file carries no unit, so
the caller names it: the Dex-Net meshes are in metres and the EGAD! meshes in
millimetres (see :mod:`precompute.catalog`); ``--units`` does it for a user's mesh.
A mesh whose longest side is outside [5 mm, 1 m] after conversion is refused, with
a hint when another unit would fit (the usual mistake is a millimetre mesh read as
metres).

Size (``fit``). ``"none"`` keeps the mesh at its file size: the Dex-Net
meshes are the physical size they were printed at (70-120 mm). ``"egad"`` applies
EGAD!'s own rule for a gripper of opening w = :data:`precompute.grasps.OPENING`
(dougsm/egad, ``scripts/prepare_meshes.py``; the paper, quoted in dougsm/egad#9:
"minimum bounding box dimension is no more than 80 % of the gripper width"): scale
so that the largest side of the oriented bounding box equals w, then, if the
smallest side exceeds 0.8 w, scale down so that it equals 0.8 w. The EGAD! files
are at the generator's size (median 92 x 99 x 100 mm), which no 80 mm gripper
could hold; the rule scales them by 0.64-0.80. The factor applied is recorded in
``LoadedMesh.scale`` (file units -> metres, the rule included).

Repair, in this order (each one is recorded in ``LoadedMesh.repairs``):

1. merge duplicate vertices, drop degenerate (zero-area) and duplicate faces;
2. split into connected pieces; drop stray pieces (under 1% of the surface area of
   the whole mesh, or with no enclosed volume while the object has some);
3. make each remaining piece's winding consistent and its normals point outwards;
4. close small holes of a piece that is not watertight (``trimesh.repair.fill_holes``),
   and when that is not enough, rebuild the piece's surface with manifold3d;
5. several substantial pieces are joined into one solid (manifold3d union). Parts
   that stay apart after the union but touch (their surfaces within
   :data:`TOUCH` = 0.5 % of the bounding-box diagonal of each other: the convex
   pieces of a V-HACD collision mesh, boxes face to face) are one rigid body, as a
   physics simulator holds them: mass properties, stable poses and grasps are
   those of the whole. Parts further apart are refused as separate bodies: one
   rigid object is expected.

A file made of closed pieces that share points (a collision mesh of convex parts
written into one file) is glued by step 1 into a shape that is not closed; when
step 4 cannot close it, the file's own pieces (faces joined by the file's vertex
indices) are taken apart instead and joined by step 5.

Scale. ``units`` converts the file to metres; ``scale`` (``--scale``) multiplies it
after that. A URDF (:mod:`precompute.urdf`) is read as the mesh it names at its
``scale`` attribute, then ``units`` (metres by default) and ``scale``.

Refusals (:class:`PrecomputeError`, one line naming the file, the defect and where
there is one the next step): missing or empty file, a file of another kind (a
problem file, a scene, a format not read), a file that does not parse as a mesh, no
triangles, degenerate geometry (all faces of zero area, or the points lie on a
plane or a line), no enclosed volume, holes that cannot be closed, separate bodies,
implausible size.

Why one file: reading, repair and sizing are the stages of :func:`load_mesh`, in
order; each is a few functions raising the same refusals, and the repair steps only
make sense on the pieces that reading produces.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import warnings
from pathlib import Path

import numpy as np

from legs_jax._files import sha256_file as file_sha256

from .errors import PrecomputeError
from .grasps import OPENING
from .urdf import read_urdf, urdf_geometry

__all__ = [
    "UNITS",
    "FITS",
    "TOUCH",
    "LoadedMesh",
    "load_mesh",
    "read_mesh_file",
    "file_sha256",
    "source_sha256",
    "check_mesh_kind",
    "egad_factor",
]

#: Length units a mesh file may be in, with their size in metres.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}

#: Size rules a mesh may be loaded with (see the module docstring).
FITS = ("none", "egad")
#: EGAD!'s cap on the smallest side of the oriented bounding box, as a fraction of
#: the gripper opening (dougsm/egad, ``scripts/prepare_meshes.py``).
EGAD_MIN_SIDE = 0.8

_MIN_SIZE = 0.005  # m, smallest longest side accepted
_MAX_SIZE = 1.0  # m, largest longest side accepted
_STRAY_AREA = 0.01  # pieces under this fraction of the total area are stray
_MESH_SUFFIXES = {".obj", ".stl", ".ply", ".off", ".glb", ".gltf"}


@dataclasses.dataclass(frozen=True, eq=False)
class LoadedMesh:
    """A watertight, outward-oriented triangle mesh in metres."""

    path: Path
    vertices: np.ndarray  # [V, 3] float64, metres
    faces: np.ndarray  # [F, 3] int64
    scale: float  # file units -> metres (the unit and the size rule)
    units: str
    fit: str  # size rule applied: "none" or "egad"
    repairs: tuple[str, ...]  # what was repaired, in words
    # what the mesh is as read: the source's digest (:func:`source_sha256`), and
    # with a factor ``scale`` other than 1 that factor too, so that the same file
    # read without it is not taken for the same mesh
    sha256: str
    source_sha256: str = ""  # of the file's bytes (a URDF's: and of its meshes)

    def trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @property
    def center_mass(self) -> np.ndarray:
        """[3] centre of mass of the solid (uniform density), metres."""
        return np.asarray(self.trimesh().center_mass, np.float64)


def source_sha256(path: str | Path) -> str:
    """What :attr:`LoadedMesh.source_sha256` is for ``path`` without loading it:
    the file's SHA-256, or for a URDF that of its bytes and of the mesh files it
    names."""
    if Path(path).suffix.lower() == ".urdf":
        h = hashlib.sha256(Path(path).read_bytes())
        for g in urdf_geometry(path):
            if g["kind"] == "mesh":
                h.update(bytes.fromhex(file_sha256(g["file"])))
        return h.hexdigest()
    return file_sha256(path)


def _scaled_sha(sha: str, scale: float) -> str:
    return hashlib.sha256(f"{sha} scale {scale!r}".encode()).hexdigest()


def check_mesh_kind(path: str | Path) -> None:
    """Refuse (naming what to do) a file that is no mesh precompute reads."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix != ".urdf" and suffix not in _MESH_SUFFIXES:
        raise _refuse(path, _wrong_kind(suffix))


#: The next step after a refusal for a shape that is not a solid.
_AS_SOLID = ": export the object as a closed solid (e.g. from MeshLab or Blender)"


def _refuse(path: Path, defect: str) -> PrecomputeError:
    return PrecomputeError(f"{path}: {defect}")


def egad_factor(extents, width: float) -> float:
    """EGAD!'s scale factor for a mesh whose oriented bounding box has sides
    ``extents`` [3], for a gripper of opening ``width``: the largest side becomes
    ``width``; then the smallest side is capped at ``EGAD_MIN_SIDE * width``."""
    ext = np.sort(np.asarray(extents, np.float64))
    factor = width / ext[2]
    if ext[0] * factor > EGAD_MIN_SIDE * width:
        factor = EGAD_MIN_SIDE * width / ext[0]
    return float(factor)


def load_mesh(
    path: str | Path, units: str = "m", fit: str = "none", scale: float = 1.0
) -> LoadedMesh:
    """Load, convert to metres (``units``, then the factor ``scale``), repair, size
    (``fit``) and check the mesh at ``path``: a mesh file, or a URDF whose
    collision mesh (else visual mesh) is read at the URDF's ``scale``.

    Raises :class:`PrecomputeError` naming the file and the defect.
    """
    import trimesh

    path = Path(path)
    if units not in UNITS:
        raise PrecomputeError(
            f"unknown unit '{units}' for {path} (choose one of {', '.join(UNITS)})"
        )
    if fit not in FITS:
        raise PrecomputeError(
            f"unknown size rule '{fit}' for {path} (choose one of {', '.join(FITS)})"
        )
    if not (np.isfinite(scale) and scale > 0):
        raise PrecomputeError(f"--scale must be a positive number, got {scale}")
    if not path.exists():
        raise _refuse(path, "no such file")
    if not path.is_file():
        raise _refuse(path, "not a file")
    suffix = path.suffix.lower()
    if suffix == ".urdf":
        vertices, faces, sha = read_urdf(path, read_mesh_file)
    else:
        vertices, faces, sha = read_mesh_file(path)

    user_scale = float(scale)
    scale = UNITS[units] * user_scale
    vertices = vertices * scale
    repairs: list[str] = []
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    raw = mesh.copy()

    # 1. merge vertices, drop degenerate and duplicate faces
    n_faces = len(mesh.faces)
    _clean(mesh)
    if len(mesh.faces) == 0:
        raise _refuse(path, "degenerate: every face has zero area" + _AS_SOLID)
    if len(mesh.faces) < n_faces:
        n_bad = n_faces - len(mesh.faces)
        repairs.append(f"dropped {_count(n_bad, 'degenerate or duplicate face')}")
    extents = np.ptp(mesh.vertices, axis=0)
    centred = mesh.vertices - mesh.vertices.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if len(sv) < 3 or sv[2] <= 1e-9 * max(sv[0], 1e-300):
        raise _refuse(
            path, "degenerate: all points lie on a plane or a line" + _AS_SOLID
        )
    _check_size(path, mesh, units)
    open_before = _count_open_edges(mesh)

    # 2-5. pieces of the merged mesh; when one cannot be closed, the file's own
    # pieces (faces joined by the file's vertex indices, each merged on its own):
    # closed solids that touch, which merging all vertices at once glues into
    # shapes that are not closed
    first = list(repairs)
    try:
        result = _assemble(path, mesh.split(only_watertight=False), extents, repairs)
    except _Holes as e:
        own = _file_pieces(raw)
        if len(own) < 2:
            raise PrecomputeError(str(e)) from None
        repairs = first + [
            f"read the file's {len(own)} pieces apart (merged at their shared "
            "points they are not closed)"
        ]
        try:
            # closed pieces of the file's own: small ones (a mug's handle) are
            # parts of the object, not sheets
            result = _assemble(path, own, extents, repairs, min_volume=1e-4)
        except _Holes:
            raise PrecomputeError(str(e)) from None
        open_before = 0
    if open_before and not any("holes" in r or "rebuilt" in r for r in repairs):
        repairs.append(f"closed holes ({open_before} open edges)")
    _check_size(path, result, units)
    vertices = np.asarray(result.vertices, np.float64)
    if fit == "egad":
        factor = egad_factor(_obb_extents(result), OPENING)
        vertices = vertices * factor
        scale *= factor
    return LoadedMesh(
        path=path,
        vertices=np.ascontiguousarray(vertices, np.float64),
        faces=np.ascontiguousarray(result.faces, np.int64),
        scale=scale,
        units=units,
        fit=fit,
        repairs=tuple(repairs),
        sha256=sha if user_scale == 1.0 else _scaled_sha(sha, user_scale),
        source_sha256=sha,
    )


def read_mesh_file(path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """(vertices [V, 3] in file units, faces [F, 3], SHA-256 of the bytes) of a mesh
    file, or a refusal naming the file, the defect and what to do."""
    import trimesh

    path = Path(path)
    if not path.exists():
        raise _refuse(path, "no such file")
    data = path.read_bytes()
    if not data.strip():
        raise _refuse(path, "empty file")
    suffix = path.suffix.lower()
    if suffix not in _MESH_SUFFIXES:
        raise _refuse(path, _wrong_kind(suffix))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(
                io.BytesIO(data), file_type=suffix[1:], force="mesh", process=False
            )
    except Exception as e:  # noqa: BLE001 - any parser failure is the same refusal
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise _refuse(path, f"not a mesh (cannot be parsed: {msg})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise _refuse(path, "not a mesh (no triangles found)")
    vertices = np.asarray(loaded.vertices, np.float64)
    faces = np.asarray(loaded.faces, np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise _refuse(path, "not a mesh (no triangles found)")
    if not np.all(np.isfinite(vertices)):
        raise _refuse(path, "vertices with NaN or infinite coordinates")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise _refuse(path, "faces refer to vertices that do not exist")
    return vertices, faces, hashlib.sha256(data).hexdigest()


def _wrong_kind(suffix: str) -> str:
    """What to do with a file that is not a mesh precompute reads."""
    known = ", ".join(sorted(_MESH_SUFFIXES | {".urdf"}))
    if suffix == ".npz":
        return (
            "a problem file, not a mesh: --mesh builds one from a mesh; use the "
            "problem file with the commands that read problems (e.g. python -m "
            "legs_jax.online simulate --object PATH, or python -m precompute "
            "report --problems FOLDER)"
        )
    if suffix in (".sdf", ".xml", ".mjcf"):
        return (
            f"a scene or model description ('{suffix}'), not supported: give the "
            f"mesh file it names, or a URDF (one of {known})"
        )
    if suffix in (".dae", ".fbx", ".blend", ".3ds", ".step", ".stp", ".iges"):
        return (
            f"a '{suffix}' file is not read: export it as .obj, .stl or .ply (e.g. "
            f"with Blender or MeshLab) and give that to --mesh (read: {known})"
        )
    return f"not a mesh file (suffix '{suffix}'; expected one of {known})"


def _clean(mesh) -> None:
    """Merge duplicate vertices, drop degenerate and duplicate faces (in place)."""
    mesh.merge_vertices()
    keep = mesh.nondegenerate_faces(height=1e-12)
    mesh.update_faces(keep)
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()


def _file_pieces(raw) -> list:
    """The pieces of the file as it indexes them (faces sharing a vertex index),
    each cleaned on its own; [] when the file indexes every triangle apart (then
    the merged pieces are all there is)."""
    import trimesh

    labels = trimesh.graph.connected_component_labels(
        raw.face_adjacency, node_count=len(raw.faces)
    )
    n = int(labels.max()) + 1 if len(labels) else 0
    if n < 2 or n > max(2, len(raw.faces) // 4):
        return []
    out = []
    for k in range(n):
        piece = raw.submesh([np.flatnonzero(labels == k)], append=True)
        _clean(piece)
        if len(piece.faces):
            out.append(piece)
    return out


class _Holes(PrecomputeError):
    """A piece whose holes cannot be closed (tried again with the file's pieces)."""


def _assemble(path: Path, pieces, extents, repairs: list[str], min_volume=0.01):
    """One rigid solid from the pieces of a mesh: stray ones dropped, each closed
    and turned outwards, those under ``min_volume`` of the largest one's volume
    dropped, the rest joined (manifold3d union); pieces that stay apart after the
    union are one body when they touch (:data:`TOUCH`), else refused."""
    total_area = float(sum(p.area for p in pieces))
    kept = [p for p in pieces if p.area >= _STRAY_AREA * total_area]
    if len(kept) < len(pieces):
        repairs.append(f"dropped {_count(len(pieces) - len(kept), 'stray piece')}")

    # 3-4. orientation and holes, per piece
    solid = [_close_piece(path, piece, repairs) for piece in kept]
    vol = np.array([abs(p.volume) for p in solid])
    if vol.max() <= 1e-9 * float(np.prod(np.maximum(extents, 1e-12))):
        raise _refuse(
            path, "no volume (an open or flat surface, not a solid)" + _AS_SOLID
        )
    # pieces without volume (sheets, or cavities of negligible size) are stray too
    substantial = [
        p for p, v in zip(solid, vol, strict=True) if v >= min_volume * vol.max()
    ]
    if len(substantial) < len(solid):
        n_flat = len(solid) - len(substantial)
        repairs.append(f"dropped {_count(n_flat, 'piece')} without volume")

    # 5. one rigid body
    if len(substantial) > 1:
        joined = _union(path, substantial)
        bodies = joined.split(only_watertight=False)
        if len(bodies) > 1:
            # the union of pieces that only touch can leave slivers of zero area
            # where they touch: dropped
            import trimesh

            _clean(joined)
            bodies = [
                b
                for b in joined.split(only_watertight=False)
                if b.volume > 1e-9 * abs(joined.volume)
            ]
            joined = trimesh.util.concatenate(bodies)
        if len(bodies) > 1:
            _touching_or_refuse(path, bodies, extents)
            repairs.append(
                f"joined {len(substantial)} pieces into one solid of "
                f"{len(bodies)} parts that touch (held as one rigid body)"
            )
        else:
            repairs.append(
                f"joined {len(substantial)} overlapping pieces into one solid"
            )
        result = joined
    else:
        result = substantial[0]
    if not result.is_watertight or result.volume <= 0:
        raise _refuse(path, "no volume after repair (not a closed solid)" + _AS_SOLID)
    return result


#: Parts of a mesh whose surfaces come within this fraction of the diagonal of the
#: mesh's bounding box of each other touch: they are one rigid body, as a physics
#: simulator holds the convex pieces of a collision mesh (V-HACD's, for one).
TOUCH = 0.005


def _touching_or_refuse(path: Path, bodies, extents) -> None:
    """Nothing when the ``bodies`` (closed, disjoint) are linked by touches
    (surfaces within ``TOUCH`` × diagonal, measured between their vertices and,
    failing that, between points spread over their faces at that spacing); else a
    refusal naming the gap."""
    from scipy.spatial import cKDTree

    diag = float(np.linalg.norm(extents))
    tol = TOUCH * diag
    n = len(bodies)
    lo = np.array([b.vertices.min(axis=0) for b in bodies]) - tol
    hi = np.array([b.vertices.max(axis=0) for b in bodies]) + tol
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    trees = [cKDTree(b.vertices) for b in bodies]
    dense: dict[int, tuple] = {}
    gaps = []
    for a in range(n):
        for b in range(a + 1, n):
            if find(a) == find(b):
                continue
            if np.any(lo[a] > hi[b]) or np.any(lo[b] > hi[a]):
                continue
            d = float(trees[b].query(bodies[a].vertices, k=1)[0].min())
            if d > tol:
                for i in (a, b):
                    if i not in dense:
                        dense[i] = _surface_points(bodies[i], tol)
                pa, tb = dense[a]
                d = min(d, float(tb.query(pa, k=1)[0].min()))
                pb_, ta = dense[b]
                d = min(d, float(ta.query(pb_, k=1)[0].min()))
            if d <= tol:
                parent[find(a)] = find(b)
            else:
                gaps.append(d)
    groups = len({find(i) for i in range(n)})
    if groups > 1:
        # the nearest parts of different groups (between their vertices)
        gaps += [
            float(trees[b].query(bodies[a].vertices, k=1)[0].min())
            for a in range(n)
            for b in range(a + 1, n)
            if find(a) != find(b)
        ]
        near = f"; the nearest are {min(gaps) * 1000:.3g} mm apart"
        raise _refuse(
            path,
            f"{groups} separate bodies (parts further apart than "
            f"{TOUCH * 100:g} % of the bounding-box diagonal, {tol * 1000:.3g} mm"
            f"{near}; one rigid object is expected): join them in a mesh editor or "
            "give each body its own file",
        )


def _surface_points(body, spacing: float):
    """(points, their KD-tree): the vertices of ``body`` with its faces cut until
    no edge is longer than ``spacing``."""
    import trimesh
    from scipy.spatial import cKDTree

    v, _ = trimesh.remesh.subdivide_to_size(
        body.vertices, body.faces, max_edge=spacing, max_iter=12
    )
    return v, cKDTree(v)


def _obb_extents(mesh) -> np.ndarray:
    """[3] sides of the minimum-volume oriented bounding box (trimesh)."""
    import trimesh

    _, extents = trimesh.bounds.oriented_bounds(mesh)
    return np.asarray(extents, np.float64)


def _close_piece(path: Path, piece, repairs: list[str]):
    """The piece made watertight with outward normals, or a refusal."""
    import trimesh

    if not piece.is_winding_consistent:
        trimesh.repair.fix_winding(piece)
        repairs.append("made face winding consistent")
    if not piece.is_watertight:
        before = len(trimesh.repair.broken_faces(piece))
        trimesh.repair.fill_holes(piece)
        if piece.is_watertight:
            repairs.append("closed holes")
        else:
            rebuilt = _manifold_rebuild(piece)
            if rebuilt is None:
                open_edges = _count_open_edges(piece)
                raise _Holes(
                    f"{path}: holes that cannot be closed ({open_edges} open edges, "
                    f"{before} faces at the borders): close them in a mesh editor "
                    "(e.g. MeshLab, Blender) or export the object as a closed solid"
                )
            piece = rebuilt
            repairs.append("rebuilt a leaking piece as a closed solid (manifold3d)")
    if piece.volume < 0:
        piece.invert()
        repairs.append("turned inside-out normals outwards")
    return piece


def _count_open_edges(piece) -> int:
    import trimesh

    groups = trimesh.grouping.group_rows(piece.edges_sorted, require_count=1)
    return len(groups)


def _manifold_rebuild(piece):
    """A closed version of an almost-closed piece via manifold3d, or None."""
    import manifold3d
    import trimesh

    try:
        m = manifold3d.Manifold(
            manifold3d.Mesh(
                vert_properties=np.asarray(piece.vertices, np.float32),
                tri_verts=np.asarray(piece.faces, np.uint32),
            )
        )
        if m.is_empty() or m.status() != manifold3d.Error.NoError:
            return None
        out = m.to_mesh()
        rebuilt = trimesh.Trimesh(
            np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts)
        )
        return rebuilt if rebuilt.is_watertight and rebuilt.volume > 0 else None
    except Exception:  # noqa: BLE001 - manifold3d refuses a non-manifold input
        return None


def _union(path: Path, pieces):
    import manifold3d
    import trimesh

    try:
        parts = [
            manifold3d.Manifold(
                manifold3d.Mesh(
                    vert_properties=np.asarray(p.vertices, np.float32),
                    tri_verts=np.asarray(p.faces, np.uint32),
                )
            )
            for p in pieces
        ]
        joined = manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add)
        out = joined.to_mesh()
    except Exception as e:  # noqa: BLE001
        raise _refuse(path, f"pieces cannot be joined into one solid ({e})") from None
    return trimesh.Trimesh(
        np.asarray(out.vert_properties, np.float64)[:, :3], np.asarray(out.tri_verts)
    )


def _count(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


def _check_size(path: Path, mesh, units: str) -> None:
    size = float(np.ptp(mesh.vertices, axis=0).max())
    if _MIN_SIZE <= size <= _MAX_SIZE:
        return
    hint = ""
    raw = size / UNITS[units]
    fits = [u for u, s in UNITS.items() if _MIN_SIZE <= raw * s <= _MAX_SIZE]
    if path.suffix.lower() == ".urdf":  # in metres, at its own scale
        hint = (
            f"; resize it with --scale (e.g. --scale {0.1 / size:.2g} for a "
            "longest side of 10 cm)"
        )
    elif fits:  # the unit giving the most object-like size (about 10 cm)
        u = min(fits, key=lambda u: abs(np.log(raw * UNITS[u] / 0.1)))
        hint = f"; is it in {u}? (pass --units {u})"
    raise _refuse(
        path,
        f"implausible size: longest side {size:.4g} m with units '{units}' "
        f"(accepted: {_MIN_SIZE * 1000:g} mm to {_MAX_SIZE:g} m){hint}",
    )
