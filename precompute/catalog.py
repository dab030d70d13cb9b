"""The 62 shipped objects: ``data/meshes/<set>/<name>.obj``.

Sets: ``dexnet_adv`` (13 Dex-Net 2.0 adversarial meshes, in metres, kept at their
physical size) and ``egad_eval`` (the 49 EGAD! evaluation objects A0-G6, in
millimetres, sized by EGAD!'s rule for the gripper: see :mod:`precompute.mesh`).

``object_id`` is the index of the object in the sorted catalogue (sorted by set,
then name), so it is stable as long as the shipped meshes do not change.
"""

from __future__ import annotations

import dataclasses
import difflib
import os
from functools import lru_cache
from pathlib import Path

from .errors import PrecomputeError

__all__ = [
    "SETS",
    "SET_UNITS",
    "SET_FIT",
    "ObjectInfo",
    "data_dir",
    "objects",
    "lookup",
    "resolve",
]

#: The object sets, in catalogue order.
SETS = ("dexnet_adv", "egad_eval")
#: Length unit of the mesh files of each set.
SET_UNITS = {"dexnet_adv": "m", "egad_eval": "mm"}
#: Size rule of each set (``precompute.mesh.FITS``).
SET_FIT = {"dexnet_adv": "none", "egad_eval": "egad"}

_REPO_DATA = Path(__file__).resolve().parent.parent / "data"


def data_dir() -> Path:
    """The data folder: ``$LEGS_JAX_DATA`` if set, else the repository's ``data/``."""
    env = os.environ.get("LEGS_JAX_DATA")
    return Path(env) if env else _REPO_DATA


@dataclasses.dataclass(frozen=True)
class ObjectInfo:
    """One catalogue object."""

    set: str  # "dexnet_adv" or "egad_eval"
    name: str  # e.g. "bar_clamp", "C3"
    mesh_path: Path  # data/meshes/<set>/<name>.obj
    object_id: int  # index in the sorted catalogue (seeding)
    units: str  # "m" or "mm", the length unit of the mesh file
    fit: str = "none"  # size rule: "none" (file size) or "egad" (EGAD!'s rule)


@lru_cache(maxsize=8)
def _scan(root: str) -> tuple[ObjectInfo, ...]:
    meshes = Path(root) / "meshes"
    found: list[tuple[str, str, Path]] = []
    for set_name in SETS:
        folder = meshes / set_name
        if not folder.is_dir():
            continue
        for path in folder.glob("*.obj"):
            found.append((set_name, path.stem, path))
    found.sort(key=lambda x: (SETS.index(x[0]), x[1]))
    return tuple(
        ObjectInfo(s, n, p, i, SET_UNITS[s], SET_FIT[s])
        for i, (s, n, p) in enumerate(found)
    )


def objects(
    set_name: str | None = None, *, root: Path | None = None
) -> list[ObjectInfo]:
    """The catalogue (all objects, or those of one set), in catalogue order."""
    root = Path(root) if root is not None else data_dir()
    infos = _scan(str(root))
    if not infos:
        raise PrecomputeError(
            f"no meshes found under {root / 'meshes'} (expected <set>/<name>.obj "
            f"for sets {', '.join(SETS)})"
        )
    if set_name is None:
        return list(infos)
    if set_name not in SETS:
        raise PrecomputeError(
            f"unknown set '{set_name}' (sets: {', '.join(SETS)})"
            + _hint(set_name, SETS)
        )
    return [i for i in infos if i.set == set_name]


def lookup(name: str, *, root: Path | None = None) -> ObjectInfo:
    """The catalogue object called ``name``."""
    infos = objects(root=root)
    for info in infos:
        if info.name == name:
            return info
    raise PrecomputeError(
        f"unknown object '{name}'" + _hint(name, [i.name for i in infos])
    )


def resolve(names, *, root: Path | None = None) -> list[ObjectInfo]:
    """Objects named by object or set names, in catalogue order, without repeats."""
    infos = objects(root=root)
    chosen: dict[str, ObjectInfo] = {}
    for n in names:
        if n in SETS:
            for i in infos:
                if i.set == n:
                    chosen[i.name] = i
        else:
            info = lookup(n, root=root)
            chosen[info.name] = info
    return sorted(chosen.values(), key=lambda i: i.object_id)


def _hint(word: str, known) -> str:
    near = difflib.get_close_matches(word, list(known), n=3)
    return f"; did you mean {', '.join(near)}?" if near else ""
