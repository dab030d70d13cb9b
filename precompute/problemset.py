"""The shipped problem set: the 62 catalogue problems as committed, checksummed data.

Why it exists. A problem file is made by Embree ray casting (which picks its SSE,
AVX2 or AVX-512 kernel from the processor), NumPy's SIMD loops and an XLA-compiled
network; on another kind of processor the same build gives other bits (on an AMD
AVX2-only machine every file differed from the files an AVX-512 machine made, and
the reservoirs themselves of two objects). Results pinned to the files then could
only be checked on the processor that made them. So, as a benchmark usually does
(and as the original BORGES code did with its problem data), the problems that the
results are made from are shipped in the repository, in the compact encoding of
:func:`legs_jax.core.problem.save_compact` (success counts, a 16-bit prior, the grasp
geometry of trial 0 for the objects that figures draw), and the sweep runs on them
by default (``--problem-source shipped``). ``python -m precompute`` still builds
problems from the meshes, and ``python -m precompute compare`` says, array by
array, how a build differs from the shipped set.

Layout: ``data/problemset/<set>/<name>.npz`` (learned prior) and
``data/problemset/prior-synthetic/dexnet_adv/<name>.npz``; ``MANIFEST.json``
records each file's SHA-256, the SHA-256 of each decoded array and how the set
was made (commit, processor, package versions). Only ``python -m precompute
ship`` writes it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from legs_jax._files import git_state, sha256_file
from legs_jax._machine import machine
from legs_jax.core import problem as problem_mod

from . import catalog as _catalog
from ._cli import add_overwrite_arg, guard_out, subcommand_parser
from .build import problems_dir
from .errors import PrecomputeError
from .grasps import SAMPLES
from .learned import default_prior

__all__ = [
    "GEOMETRY_OBJECTS",
    "MANIFEST",
    "compare",
    "machine",
    "manifest",
    "pack",
    "paths",
    "set_dir",
]

MANIFEST = "MANIFEST.json"
#: Objects whose grasp geometry (trial 0) is shipped: the case study's figures
#: draw them, the online session's example simulates bar_clamp.
GEOMETRY_OBJECTS = ("bar_clamp", "climbing_hold", "C3", "F6", "turbine_housing")
#: Priors shipped, and the sets shipped with each.
SHIPPED = {"learned": ("dexnet_adv", "egad_eval"), "synthetic": ("dexnet_adv",)}
# Arrays compared between a build and the shipped set (what the engine reads,
# then the geometry).
_ENGINE = ("landing", "topple", "pose_valid", "valid", "robustness", "prior")
_GEOM = ("pose_transform", "grasp_center", "grasp_axis", "grasp_width", "grasp_height")


def set_dir(data_dir: Path | None = None) -> Path:
    """``<data>/problemset``."""
    base = Path(data_dir) if data_dir is not None else _catalog.data_dir()
    return base / "problemset"


def _rel(info, prior: str) -> str:
    sub = "" if prior == "learned" else f"prior-{prior}/"
    return f"{sub}{info.set}/{info.name}.npz"


def manifest(data_dir: Path | None = None) -> dict[str, Any]:
    """The shipped set's ``MANIFEST.json`` (PrecomputeError when absent)."""
    path = set_dir(data_dir) / MANIFEST
    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError:
        raise PrecomputeError(
            f"the shipped problem set is missing ({path} not found); restore it "
            "with `git checkout -- data/problemset`, or build the problems from "
            "the meshes with --problem-source built"
        ) from None
    except (OSError, json.JSONDecodeError) as e:
        raise PrecomputeError(f"{path}: unreadable ({e})") from None


def paths(
    names: Sequence[str],
    prior: str = "learned",
    *,
    data_dir: Path | None = None,
    verify: bool = True,
) -> dict[str, Path]:
    """The shipped problem file of each named object (object or set names),
    checked against the SHA-256 that ``MANIFEST.json`` records: a missing or
    changed file is refused with the command that restores it."""
    if prior not in SHIPPED:
        raise PrecomputeError(
            f"no shipped problems with the {prior} prior (shipped: "
            f"{', '.join(SHIPPED)}); use --problem-source built"
        )
    infos = _catalog.resolve(list(names), root=data_dir)
    missing_sets = sorted({i.set for i in infos} - set(SHIPPED[prior]))
    if missing_sets:
        raise PrecomputeError(
            f"no shipped problems of set {missing_sets[0]} with the {prior} prior; "
            "use --problem-source built"
        )
    man = manifest(data_dir)
    root = set_dir(data_dir)
    out = {}
    for info in infos:
        rel = _rel(info, prior)
        rec = man.get("files", {}).get(rel)
        path = root / rel
        if rec is None or not path.is_file():
            raise PrecomputeError(
                f"shipped problem {path} is missing; restore it with "
                "`git checkout -- data/problemset`"
            )
        if verify and sha256_file(path) != rec["sha256"]:
            raise PrecomputeError(
                f"shipped problem {path} differs from the SHA-256 that "
                f"{root / MANIFEST} records; restore it with "
                "`git checkout -- data/problemset`"
            )
        out[info.name] = path
    return out


def array_digests(path: Path, data_dir: Path | None = None) -> dict[str, str] | None:
    """The recorded digests of a shipped file's decoded arrays (None for a file
    outside the shipped set)."""
    root = set_dir(data_dir).resolve()
    try:
        rel = Path(path).resolve().relative_to(root).as_posix()
    except ValueError:
        return None
    try:
        rec = manifest(data_dir).get("files", {}).get(rel)
    except PrecomputeError:
        return None
    return None if rec is None else dict(rec.get("arrays", {}))


def pack(
    problems_dir: Path,
    *,
    data_dir: Path | None = None,
    priors: Sequence[str] = tuple(SHIPPED),
    progress: bool = True,
) -> dict[str, Any]:
    """Write the shipped set from built problem files (``problems_dir``: the
    default prior's folder, with ``prior-<kind>/`` beside for the others) and its
    ``MANIFEST.json``. Every object of every shipped set must be built."""
    root = set_dir(data_dir)
    files: dict[str, Any] = {}
    todo = []
    for prior in priors:
        sub = Path(problems_dir)
        if prior != default_prior():
            sub = sub / f"prior-{prior}"
        for set_ in SHIPPED[prior]:
            for info in _catalog.objects(set_, root=data_dir):
                todo.append((prior, info, sub / info.set / f"{info.name}.npz"))
    absent = [str(p) for _, _, p in todo if not p.is_file()]
    if absent:
        raise PrecomputeError(
            f"{len(absent)} problem files are not built (first: {absent[0]}); "
            "build them with `python -m precompute --all` and "
            "`python -m precompute --set dexnet_adv --prior synthetic`"
        )
    from tqdm.auto import tqdm

    for prior, info, src in tqdm(todo, desc="ship", unit="obj", disable=not progress):
        pb = problem_mod.load(src)
        kind = problem_mod.prior_kind(pb.meta)
        if kind != prior:
            raise PrecomputeError(f"{src} carries the {kind} prior, not {prior}")
        rel = _rel(info, prior)
        g = 1 if info.name in GEOMETRY_OBJECTS else 0
        dst = root / rel
        problem_mod.save_compact(pb, dst, samples=SAMPLES, geometry_trials=g)
        shipped = problem_mod.load(dst)
        files[rel] = {
            "sha256": sha256_file(dst),
            "bytes": dst.stat().st_size,
            "arrays": problem_mod.array_digests(shipped),
            "built_sha256": sha256_file(src),
            "build_hash": pb.meta.get("build_hash"),
        }
    man = {
        "description": "the problems the shipped results are made from "
        "(precompute/problemset.py)",
        "encoding": problem_mod.COMPACT,
        "made_by": {"git": git_state(), **machine()},
        "files": dict(sorted(files.items())),
    }
    text = json.dumps(man, indent=1, sort_keys=True) + "\n"
    (root / MANIFEST).write_text(text)
    return man


def compare_problems(built, shipped, geometry_trials: int) -> dict[str, str]:
    """Array -> how ``built`` differs from ``shipped`` (only differing arrays).

    q is compared after the 16-bit quantisation the shipped set applies; grasp
    geometry only over the trials the shipped file holds."""
    diff: dict[str, str] = {}
    # q as the shipped encoding holds it
    q = problem_mod.dequantize_prior(problem_mod.quantize_prior(built.prior))
    for f in _ENGINE + _GEOM:
        a = q if f == "prior" else getattr(built, f)
        b = getattr(shipped, f)
        if f in _GEOM and f != "pose_transform":
            if geometry_trials == 0:
                continue
            a, b = a[:geometry_trials], b[:geometry_trials]
        if a.shape != b.shape:
            diff[f] = f"shape {a.shape} vs {b.shape}"
            continue
        if a.dtype == bool:
            n = int(np.count_nonzero(a != b))
            if n:
                diff[f] = f"{n} of {a.size} entries differ"
            continue
        ne = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        n = int(np.count_nonzero(ne))
        if n:
            d = float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64))))
            diff[f] = f"{n} of {a.size} entries differ (max |diff| {d:.3g})"
    return diff


def compare(
    names: Sequence[str],
    problems_dir: Path,
    *,
    prior: str = "learned",
    data_dir: Path | None = None,
) -> dict[str, dict[str, str] | str]:
    """Object -> {array: difference} between the built files in ``problems_dir``
    and the shipped set ({} when every array is equal; a string when the built
    file is absent)."""
    shipped = paths(names, prior, data_dir=data_dir)
    out: dict[str, dict[str, str] | str] = {}
    for info in _catalog.resolve(list(names), root=data_dir):
        src = Path(problems_dir) / info.set / f"{info.name}.npz"
        if not src.is_file():
            out[info.name] = f"not built ({src})"
            continue
        s = problem_mod.load(shipped[info.name])
        b = problem_mod.load(src)
        out[info.name] = compare_problems(b, s, int(s.meta.get("geometry_trials", 0)))
    return out


def format_comparison(result: dict[str, dict[str, str] | str]) -> str:
    """The report of :func:`compare`, one line per object."""
    lines = []
    same = [n for n, d in result.items() if d == {}]
    for name, d in result.items():
        if isinstance(d, str):
            lines.append(f"{name}: {d}")
        elif d:
            parts = "; ".join(f"{f}: {why}" for f, why in d.items())
            lines.append(f"{name}: differs: {parts}")
    lines.append(
        f"{len(same)} of {len(result)} built problems equal the shipped set in every "
        "array (q after its 16-bit quantisation)"
    )
    return "\n".join(lines)


def _names(a) -> list[str]:
    if a.object:
        return list(a.object)
    if a.set_name:
        return [a.set_name]
    return list(_catalog.SETS)


def main_compare(argv: Sequence[str]) -> int:
    """``python -m precompute compare``."""
    ap = subcommand_parser(
        "compare",
        "Compare problem files built from the meshes on this machine "
        "(python -m precompute --all) with the shipped problem set "
        "(data/problemset), array by array: which arrays differ, in how many "
        "entries and by how much. The sweep runs on the shipped set unless told "
        "--problem-source built.",
    )
    ap.add_argument("--set", dest="set_name", choices=_catalog.SETS)
    ap.add_argument("--object", nargs="+", metavar="NAME")
    ap.add_argument("--prior", choices=sorted(SHIPPED), default="learned")
    a = ap.parse_args(list(argv))
    folder = a.problems if a.problems is not None else problems_dir(prior=a.prior)
    names = _names(a)
    if a.prior != "learned" and not a.object and not a.set_name:
        names = list(SHIPPED[a.prior])
    result = compare(names, folder, prior=a.prior)
    print(format_comparison(result))
    print(f"compared {folder} with {set_dir()} (no file written)")
    return 0


def main_ship(argv: Sequence[str]) -> int:
    """``python -m precompute ship``."""
    ap = subcommand_parser(
        "ship",
        "Write the shipped problem set (data/problemset, its "
        "MANIFEST.json) from the built problem files of every catalogue object "
        "(learned prior) and of the Dex-Net objects (synthetic prior). For the "
        "maintainers: the committed results are made from the shipped set, so "
        "shipping a new one means running the sweep again; replacing the "
        "committed set needs --overwrite.",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress bar")

    add_overwrite_arg(ap, "data/problemset (the shipped set)")
    a = ap.parse_args(list(argv))
    folder = a.problems if a.problems is not None else problems_dir()
    guard_out(set_dir(), a.overwrite, what="data folder")
    man = pack(folder, progress=not a.quiet)
    total = sum(f["bytes"] for f in man["files"].values())
    print(
        f"shipped {len(man['files'])} problem files, {total / 1e6:.1f} MB -> "
        f"{set_dir()}"
    )
    return 0
