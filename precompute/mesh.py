"""Loading a mesh in metres, repairing what can be repaired, refusing the rest.

Units. Every length inside precompute is in metres. A mesh file carries no unit, so
the caller names it: the Dex-Net meshes are in metres and the EGAD! meshes in
millimetres (see :mod:`precompute.catalog`); ``--units`` does it for a user's mesh.
A mesh whose longest side is outside [5 mm, 1 m] after conversion is refused, with
a hint when another unit would fit (the usual mistake is a millimetre mesh read as
metres).

Size (``fit``, SPEC §6). ``"none"`` keeps the mesh at its file size: the Dex-Net
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
5. several substantial pieces are joined into one solid (manifold3d union); if they
   stay apart (separate bodies) the mesh is refused: one rigid object is expected.

Refusals (:class:`PrecomputeError`, one line naming the file and the defect): missing
or empty file, a file that does not parse as a mesh, no triangles, degenerate
geometry (all faces of zero area, or the points lie on a plane or a line), no
enclosed volume, holes that cannot be closed, separate bodies, implausible size.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import warnings
from pathlib import Path

import numpy as np

from .errors import PrecomputeError

__all__ = ["UNITS", "FITS", "LoadedMesh", "load_mesh", "file_sha256", "egad_factor"]

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
    sha256: str  # of the file's bytes

    def trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @property
    def center_mass(self) -> np.ndarray:
        """[3] centre of mass of the solid (uniform density), metres."""
        return np.asarray(self.trimesh().center_mass, np.float64)


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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


def load_mesh(path: str | Path, units: str = "m", fit: str = "none") -> LoadedMesh:
    """Load, convert to metres, repair, size (``fit``) and check the mesh at
    ``path``.

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
    if not path.exists():
        raise _refuse(path, "no such file")
    if not path.is_file():
        raise _refuse(path, "not a file")
    data = path.read_bytes()
    if not data.strip():
        raise _refuse(path, "empty file")
    suffix = path.suffix.lower()
    if suffix not in _MESH_SUFFIXES:
        raise _refuse(
            path,
            f"not a mesh file (suffix '{suffix}'; expected one of "
            f"{', '.join(sorted(_MESH_SUFFIXES))})",
        )
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

    scale = UNITS[units]
    vertices = vertices * scale
    repairs: list[str] = []
    mesh = trimesh.Trimesh(vertices, faces, process=False)

    # 1. merge vertices, drop degenerate and duplicate faces
    n_faces = len(mesh.faces)
    mesh.merge_vertices()
    keep = mesh.nondegenerate_faces(height=1e-12)
    mesh.update_faces(keep)
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise _refuse(path, "degenerate: every face has zero area")
    if len(mesh.faces) < n_faces:
        n_bad = n_faces - len(mesh.faces)
        repairs.append(f"dropped {_count(n_bad, 'degenerate or duplicate face')}")
    extents = np.ptp(mesh.vertices, axis=0)
    centred = mesh.vertices - mesh.vertices.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if len(sv) < 3 or sv[2] <= 1e-9 * max(sv[0], 1e-300):
        raise _refuse(path, "degenerate: all points lie on a plane or a line")
    _check_size(path, mesh, units)
    open_before = _count_open_edges(mesh)

    # 2. pieces; stray ones dropped
    pieces = mesh.split(only_watertight=False)
    total_area = float(sum(p.area for p in pieces))
    kept = [p for p in pieces if p.area >= _STRAY_AREA * total_area]
    if len(kept) < len(pieces):
        repairs.append(f"dropped {_count(len(pieces) - len(kept), 'stray piece')}")

    # 3-4. orientation and holes, per piece
    solid = []
    for piece in kept:
        piece = _close_piece(path, piece, repairs)
        solid.append(piece)
    vol = np.array([abs(p.volume) for p in solid])
    if vol.max() <= 1e-9 * float(np.prod(np.maximum(extents, 1e-12))):
        raise _refuse(path, "no volume (an open or flat surface, not a solid)")
    # pieces without volume (sheets, or cavities of negligible size) are stray too
    substantial = [p for p, v in zip(solid, vol, strict=True) if v >= 0.01 * vol.max()]
    if len(substantial) < len(solid):
        n_flat = len(solid) - len(substantial)
        repairs.append(f"dropped {_count(n_flat, 'piece')} without volume")

    # 5. one rigid body
    if len(substantial) > 1:
        joined = _union(path, substantial)
        if len(joined.split(only_watertight=False)) > 1:
            raise _refuse(
                path,
                f"{len(substantial)} separate bodies (one rigid object is expected)",
            )
        repairs.append(f"joined {len(substantial)} overlapping pieces into one solid")
        result = joined
    else:
        result = substantial[0]
    if not result.is_watertight or result.volume <= 0:
        raise _refuse(path, "no volume after repair (not a closed solid)")
    if open_before and not any("holes" in r or "rebuilt" in r for r in repairs):
        repairs.append(f"closed holes ({open_before} open edges)")
    _check_size(path, result, units)
    vertices = np.asarray(result.vertices, np.float64)
    if fit == "egad":
        from .grasps import OPENING

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
        sha256=hashlib.sha256(data).hexdigest(),
    )


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
                raise _refuse(
                    path,
                    f"holes that cannot be closed ({open_edges} open edges, "
                    f"{before} faces at the borders)",
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
    if fits:  # the unit giving the most object-like size (about 10 cm)
        u = min(fits, key=lambda u: abs(np.log(raw * UNITS[u] / 0.1)))
        hint = f"; is it in {u}? (pass --units {u})"
    raise _refuse(
        path,
        f"implausible size: longest side {size:.4g} m with units '{units}' "
        f"(accepted: {_MIN_SIZE * 1000:g} mm to {_MAX_SIZE:g} m){hint}",
    )
