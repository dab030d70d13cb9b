"""The mesh of a URDF asset: what ``python -m precompute --mesh asset.urdf`` builds.

A URDF names its shape in ``<link><collision><geometry>`` (what a simulator
touches) and ``<link><visual><geometry>`` (what it draws). The collision geometry
is read, else the visual geometry: ``<mesh filename="..." scale="sx sy sz"/>`` (a
file name relative to the URDF's folder; ``package://NAME/`` and ``file://``
prefixes are stripped and the rest looked for beside the URDF), ``<box>``,
``<sphere>`` and ``<cylinder>``, each moved by its ``<origin xyz rpy>``. Lengths in a
URDF are metres, so ``--units`` defaults to ``m`` for it. A model of several links
(joints, an articulated robot) is refused: one rigid object is expected.
"""

from __future__ import annotations

import hashlib
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .errors import PrecomputeError

__all__ = ["read_urdf", "urdf_geometry"]


def _refuse(path: Path, defect: str) -> PrecomputeError:
    return PrecomputeError(f"{path}: {defect}")


def _floats(text: str | None, n: int, default: float, path: Path, what: str):
    if text is None or not text.strip():
        return np.full(n, default, np.float64)
    try:
        vals = np.array([float(x) for x in text.split()], np.float64)
    except ValueError:
        raise _refuse(path, f"{what} is not a list of numbers: '{text}'") from None
    if len(vals) == 1 and n > 1:
        vals = np.full(n, vals[0])
    if len(vals) != n or not np.all(np.isfinite(vals)):
        raise _refuse(path, f"{what} needs {n} numbers, got '{text}'")
    return vals


def _origin(elem, path: Path) -> np.ndarray:
    """4x4 transform of an element's ``<origin xyz rpy>`` (URDF: fixed-axis roll,
    pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll))."""
    tf = np.eye(4)
    o = elem.find("origin")
    if o is None:
        return tf
    xyz = _floats(o.get("xyz"), 3, 0.0, path, "origin xyz")
    r, p, y = _floats(o.get("rpy"), 3, 0.0, path, "origin rpy")
    cr, sr, cp, sp, cy, sy = (
        np.cos(r),
        np.sin(r),
        np.cos(p),
        np.sin(p),
        np.cos(y),
        np.sin(y),
    )
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    tf[:3, :3] = rz @ ry @ rx
    tf[:3, 3] = xyz
    return tf


def _resolve(path: Path, filename: str) -> Path:
    """The file a ``<mesh filename>`` names, relative to the URDF's folder."""
    base = path.parent
    name = filename.strip()
    if name.startswith("file://"):
        name = name[len("file://") :]
    candidates = []
    if name.startswith("package://"):
        rest = Path(name[len("package://") :])
        # package://PKG/a/b.obj: a/b.obj beside the URDF, in its parent folders
        # (a package's root is usually above the URDF's own folder), PKG/a/b.obj
        parts = rest.parts[1:] if len(rest.parts) > 1 else rest.parts
        sub = Path(*parts)
        candidates += [base / sub, base / rest]
        candidates += [up / sub for up in list(base.parents)[:3]]
        candidates.append(base / rest.name)
    else:
        p = Path(name)
        candidates += [p if p.is_absolute() else base / p, base / p.name]
    for c in candidates:
        if c.is_file():
            return c
    raise _refuse(
        path,
        f"the mesh it names, '{filename}', is not found (looked for "
        f"{candidates[0]}): put it there, or pass the mesh file itself with --mesh",
    )


def urdf_geometry(path: str | Path) -> list[dict]:
    """The shapes of the URDF at ``path``: one dict per ``<geometry>`` read
    (``kind``: mesh, box, sphere or cylinder; ``file`` and ``scale`` [3] of a mesh;
    ``size`` of a primitive; ``origin`` 4x4; ``source``: collision or visual)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as e:
        raise _refuse(path, f"not a URDF (cannot be parsed: {e})") from None
    if root.tag != "robot":
        raise _refuse(
            path, f"not a URDF (its root element is <{root.tag}>, not <robot>)"
        )
    links = [
        lk
        for lk in root.findall("link")
        if lk.find("collision/geometry") is not None
        or lk.find("visual/geometry") is not None
    ]
    if not links:
        raise _refuse(path, "no link with a collision or visual geometry")
    if len(links) > 1:
        raise _refuse(
            path,
            f"{len(links)} links with geometry (an articulated model; one rigid "
            "object is expected): pass the mesh of one part with --mesh",
        )
    link = links[0]
    for source in ("collision", "visual"):
        shapes = []
        for elem in link.findall(source):
            geom = elem.find("geometry")
            if geom is None:
                continue
            tf = _origin(elem, path)
            for g in geom:
                if g.tag == "mesh":
                    fname = g.get("filename")
                    if not fname:
                        raise _refuse(path, "a <mesh> without a filename")
                    scale = _floats(g.get("scale"), 3, 1.0, path, "mesh scale")
                    if np.any(scale <= 0):
                        raise _refuse(path, f"mesh scale must be positive, got {scale}")
                    shapes.append(
                        {
                            "kind": "mesh",
                            "file": _resolve(path, fname),
                            "scale": scale,
                            "origin": tf,
                            "source": source,
                        }
                    )
                elif g.tag == "box":
                    size = _floats(g.get("size"), 3, np.nan, path, "box size")
                    shapes.append(_prim("box", size, tf, source))
                elif g.tag == "sphere":
                    r = _floats(g.get("radius"), 1, np.nan, path, "sphere radius")
                    shapes.append(_prim("sphere", r, tf, source))
                elif g.tag == "cylinder":
                    r = _floats(g.get("radius"), 1, np.nan, path, "cylinder radius")
                    h = _floats(g.get("length"), 1, np.nan, path, "cylinder length")
                    shapes.append(_prim("cylinder", np.r_[r, h], tf, source))
        if shapes:
            return shapes
    raise _refuse(path, "no mesh, box, sphere or cylinder in its link's geometry")


def _prim(kind, size, tf, source) -> dict:
    if np.any(np.asarray(size) <= 0):
        raise PrecomputeError(f"a {kind} of size {list(size)}: sizes must be positive")
    return {"kind": kind, "size": size, "origin": tf, "source": source}


def read_urdf(
    path: str | Path, read_mesh_file: Callable[[Path], tuple]
) -> tuple[np.ndarray, np.ndarray, str]:
    """(vertices [V, 3] in the URDF's units, with each mesh's scale and origin
    applied; faces [F, 3]; SHA-256 of the URDF's bytes and of every mesh file it
    names), the shapes of :func:`urdf_geometry` as one mesh; each mesh file read
    by ``read_mesh_file`` (:func:`precompute.mesh.read_mesh_file`: vertices,
    faces, SHA-256)."""
    import trimesh

    path = Path(path)
    h = hashlib.sha256(path.read_bytes())
    verts, faces, n = [], [], 0
    for shape in urdf_geometry(path):
        if shape["kind"] == "mesh":
            v, f, sha = read_mesh_file(shape["file"])
            v = v * shape["scale"]
            h.update(bytes.fromhex(sha))
        else:
            size = shape["size"]
            if shape["kind"] == "box":
                m = trimesh.creation.box(extents=size)
            elif shape["kind"] == "sphere":
                m = trimesh.creation.icosphere(subdivisions=3, radius=size[0])
            else:
                m = trimesh.creation.cylinder(
                    radius=size[0], height=size[1], sections=48
                )
            v, f = np.asarray(m.vertices), np.asarray(m.faces)
        tf = shape["origin"]
        verts.append(v @ tf[:3, :3].T + tf[:3, 3])
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces), h.hexdigest()
