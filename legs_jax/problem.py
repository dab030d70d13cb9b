"""The problem of one object (SPEC §1), its file format, and batches of problems.

A problem is everything the bandit environment needs about one object: where a drop
lands, where a failed grasp topples it, and for each of T reservoirs of K grasps per
pose the ground-truth success probability and the prior quality. It is stored as one
``.npz`` file whose arrays carry the names below. ``load`` validates every array and
refuses a bad file with a :class:`ProblemFileError` naming the file and the field.

Dimension letters: O objects, T trials (reservoirs), P poses, K grasps per pose.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from legs_jax._files import atomic_write

__all__ = [
    "peek",
    "FORMAT_VERSION",
    "Problem",
    "ProblemBatch",
    "ProblemFileError",
    "load",
    "save",
    "stack",
]

FORMAT_VERSION = 1

# Probabilities are stored in float32; sums are checked to this tolerance.
_SUM_TOL = 1e-4


class ProblemFileError(ValueError):
    """A problem file (or in-memory problem) is malformed.

    The message always names the file (or ``<memory>``) and the offending field.
    """

    def __init__(self, path: str | os.PathLike | None, field: str, reason: str):
        self.path = str(path) if path is not None else "<memory>"
        self.field = field
        self.reason = reason
        super().__init__(f"{self.path}: field '{field}': {reason}")


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """One object after precompute (SPEC §1). All arrays are NumPy arrays.

    Padding beyond the object's own poses (``pose_valid`` False) and beyond its own
    grasps (``valid`` False) is allowed; it is never sampled and never counted.
    """

    name: str
    landing: np.ndarray  # [P] float32, λ_s; sums to 1 over valid poses, 0 on padding
    topple: np.ndarray  # [P, P] float32, row s: next pose after a failed grasp in s
    robustness: np.ndarray  # [T, P, K] float32, ground-truth success probability p
    prior: np.ndarray  # [T, P, K] float32, prior quality q in [0, 1]
    valid: np.ndarray  # [T, P, K] bool, slot holds a real grasp
    grasp_center: np.ndarray  # [T, P, K, 3] float32, jaw centre in the pose frame (m)
    grasp_axis: np.ndarray  # [T, P, K, 3] float32, unit jaw axis in the pose frame
    grasp_width: np.ndarray  # [T, P, K] float32, contact-to-contact width (m)
    grasp_height: np.ndarray  # [T, P, K] float32, closing height above table (m)
    pose_transform: np.ndarray  # [P, 4, 4] float32, mesh frame -> pose frame
    pose_valid: np.ndarray  # [P] bool, pose is real (not padding)
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)  # JSON-able

    # ------------------------------------------------------------------ shapes
    @property
    def num_trials(self) -> int:
        return int(self.robustness.shape[0])

    @property
    def num_poses(self) -> int:
        """Number of pose slots P (real poses plus padding)."""
        return int(self.robustness.shape[1])

    @property
    def num_real_poses(self) -> int:
        return int(self.pose_valid.sum())

    @property
    def num_grasps(self) -> int:
        """Number of grasp slots K per pose (real grasps plus padding)."""
        return int(self.robustness.shape[2])

    # ---------------------------------------------------------- derived values
    def p_star(self) -> np.ndarray:
        """[T, P] best ground-truth robustness in each trial's reservoir of each pose
        (0 for a pose with no valid grasp)."""
        return np.where(self.valid, self.robustness, 0.0).max(axis=-1)

    def validate(self, path: str | os.PathLike | None = None) -> Problem:
        """Check shapes, dtypes and values; raise :class:`ProblemFileError`."""
        _validate(self, path)
        return self

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Problem):
            return NotImplemented
        if self.name != other.name or self.meta != other.meta:
            return False
        for f in _ARRAY_FIELDS:
            a, b = getattr(self, f), getattr(other, f)
            if a.dtype != b.dtype or a.shape != b.shape or not np.array_equal(a, b):
                return False
        return True

    __hash__ = None  # type: ignore[assignment]


# Field name -> (dtype kind, shape in letters). "3" and "4" are literal sizes.
_SCHEMA: dict[str, tuple[str, tuple[str, ...]]] = {
    "landing": ("f", ("P",)),
    "topple": ("f", ("P", "P")),
    "robustness": ("f", ("T", "P", "K")),
    "prior": ("f", ("T", "P", "K")),
    "valid": ("b", ("T", "P", "K")),
    "grasp_center": ("f", ("T", "P", "K", "3")),
    "grasp_axis": ("f", ("T", "P", "K", "3")),
    "grasp_width": ("f", ("T", "P", "K")),
    "grasp_height": ("f", ("T", "P", "K")),
    "pose_transform": ("f", ("P", "4", "4")),
    "pose_valid": ("b", ("P",)),
}
_ARRAY_FIELDS = tuple(_SCHEMA)
# Grasp and pose geometry: only drawing needs it, so a file may leave it out (an
# abstract bandit problem); it then loads as zeros (identity pose transforms) and
# ``meta["geometry"]`` is False.
_GEOMETRY = (
    "grasp_center",
    "grasp_axis",
    "grasp_width",
    "grasp_height",
    "pose_transform",
)
# Arrays the format requires in a file. pose_valid may be absent (all poses real).
_REQUIRED = tuple(f for f in _ARRAY_FIELDS if f != "pose_valid" and f not in _GEOMETRY)


def _validate(pb: Problem, path: str | os.PathLike | None) -> None:
    dims: dict[str, int] = {}
    for field, (kind, letters) in _SCHEMA.items():
        arr = getattr(pb, field)
        if not isinstance(arr, np.ndarray):
            raise ProblemFileError(
                path, field, f"expected a NumPy array, got {type(arr)}"
            )
        if kind == "f" and arr.dtype.kind not in "f":
            raise ProblemFileError(
                path, field, f"expected floats, got dtype {arr.dtype}"
            )
        if kind == "b" and arr.dtype != np.bool_:
            raise ProblemFileError(
                path, field, f"expected booleans, got dtype {arr.dtype}"
            )
        if arr.ndim != len(letters):
            raise ProblemFileError(
                path,
                field,
                f"expected {len(letters)} dimensions [{', '.join(letters)}], "
                f"got shape {arr.shape}",
            )
        for axis, (letter, size) in enumerate(zip(letters, arr.shape, strict=True)):
            if letter.isdigit():
                if size != int(letter):
                    raise ProblemFileError(
                        path, field, f"axis {axis} must have size {letter}, got {size}"
                    )
                continue
            if letter in dims and dims[letter] != size:
                raise ProblemFileError(
                    path,
                    field,
                    f"inconsistent shape {arr.shape}: {letter} = {size} here but "
                    f"{dims[letter]} in earlier fields",
                )
            dims[letter] = size
        if kind == "f" and not np.all(np.isfinite(arr)):
            raise ProblemFileError(path, field, "contains NaN or infinite values")
    if dims["P"] < 1 or dims["T"] < 1 or dims["K"] < 1:
        raise ProblemFileError(path, "robustness", f"empty shape {pb.robustness.shape}")

    pv = pb.pose_valid
    if not pv.any():
        raise ProblemFileError(path, "pose_valid", "no real pose")
    for field in ("robustness", "prior"):
        arr = getattr(pb, field)
        if arr.min() < 0.0 or arr.max() > 1.0:
            raise ProblemFileError(
                path,
                field,
                f"values must lie in [0, 1], found [{arr.min():.4g}, {arr.max():.4g}]",
            )
    if pb.landing.min() < 0.0:
        raise ProblemFileError(path, "landing", "negative probability")
    if np.any(pb.landing[~pv] != 0.0):
        raise ProblemFileError(path, "landing", "non-zero probability on a padded pose")
    total = float(pb.landing.sum(dtype=np.float64))
    if abs(total - 1.0) > _SUM_TOL:
        raise ProblemFileError(path, "landing", f"must sum to 1, sums to {total:.6g}")
    if pb.topple.min() < 0.0:
        raise ProblemFileError(path, "topple", "negative probability")
    rows = pb.topple.sum(axis=1, dtype=np.float64)
    bad = np.flatnonzero(pv & (np.abs(rows - 1.0) > _SUM_TOL))
    if bad.size:
        s = int(bad[0])
        raise ProblemFileError(
            path, "topple", f"row {s} must sum to 1, sums to {rows[s]:.6g}"
        )
    if np.any(pb.topple[:, ~pv] != 0.0):
        raise ProblemFileError(
            path, "topple", "probability of toppling onto a padded pose"
        )
    if np.any(pb.valid[:, ~pv, :]):
        raise ProblemFileError(path, "valid", "valid grasps on a padded pose")
    if not isinstance(pb.meta, dict):
        raise ProblemFileError(path, "meta", "must be a dict")


# ----------------------------------------------------------------------------- I/O


def _npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
    return buf.getvalue()


def save(problem: Problem, path: str | os.PathLike) -> Path:
    """Validate and write ``problem`` to ``path`` (``.npz``), atomically.

    The file is byte-for-byte deterministic: fixed member order and timestamps.
    """
    path = Path(path)
    problem.validate(path)
    members: list[tuple[str, bytes]] = []
    for f in _ARRAY_FIELDS:
        members.append((f + ".npy", _npy_bytes(getattr(problem, f))))
    header = {
        "format_version": FORMAT_VERSION,
        "name": problem.name,
        "meta": problem.meta,
    }
    text = json.dumps(header, sort_keys=True)
    members.append(("meta_json.npy", _npy_bytes(np.array(text))))

    def write(fh) -> None:
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in members:
                info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                z.writestr(info, data, compresslevel=6)

    return atomic_write(path, write)


def prior_kind(meta: dict[str, Any]) -> str:
    """Which prior q a problem file carries, from its meta: "learned" (the
    network of ``precompute.learned``), "synthetic" (the stand-in made from p;
    files built before the learned prior record no kind) or "unknown" (a file
    made elsewhere)."""
    kind = meta.get("prior_kind")
    if kind:
        return str(kind)
    prior = meta.get("prior")
    if isinstance(prior, str) and prior in ("learned", "synthetic"):
        return prior
    return "synthetic" if isinstance(prior, dict) else "unknown"


def peek(path: str | os.PathLike) -> dict[str, Any]:
    """The header of a problem file without loading its arrays: ``name``,
    ``meta`` and ``shapes`` (field -> array shape, for ``landing`` and
    ``robustness``). Raises an ``OSError``, ``ValueError`` or ``KeyError`` for an
    unreadable file (:func:`load` says what is wrong with it)."""
    shapes = {}
    with zipfile.ZipFile(path) as z:
        for field in ("landing", "robustness"):
            with z.open(field + ".npy") as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _, _ = np.lib.format.read_array_header_1_0(fh)
                elif version == (2, 0):
                    shape, _, _ = np.lib.format.read_array_header_2_0(fh)
                else:
                    with z.open(field + ".npy") as full:
                        shape = np.lib.format.read_array(full).shape
                shapes[field] = tuple(shape)
        raw = z.read("meta_json.npy")
    arr = np.load(io.BytesIO(raw), allow_pickle=False)
    header = json.loads(str(arr.reshape(-1)[0]))
    return {
        "name": header.get("name"),
        "meta": dict(header.get("meta", {})),
        "shapes": shapes,
    }


def _no_geometry(tpk: tuple[int, ...]) -> dict[str, np.ndarray]:
    """Placeholder geometry of a problem without any: zeros, identity poses."""
    T, P, K = tpk
    f32 = np.float32
    return {
        "grasp_center": np.zeros((T, P, K, 3), f32),
        "grasp_axis": np.zeros((T, P, K, 3), f32),
        "grasp_width": np.zeros((T, P, K), f32),
        "grasp_height": np.zeros((T, P, K), f32),
        "pose_transform": np.tile(np.eye(4, dtype=f32), (P, 1, 1)),
    }


def load(path: str | os.PathLike) -> Problem:
    """Read and validate a problem file. Raises :class:`ProblemFileError`."""
    path = Path(path)
    if not path.is_file():
        raise ProblemFileError(path, "<file>", "no such file")
    try:
        npz = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is refused the same way
        raise ProblemFileError(
            path, "<file>", f"not a readable .npz file ({e})"
        ) from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise ProblemFileError(
            path, "<file>", "not an .npz archive (a bare .npy array?)"
        )
    with npz:
        arrays: dict[str, np.ndarray] = {}
        for f in _ARRAY_FIELDS:
            if f not in npz.files:
                if f in _REQUIRED:
                    raise ProblemFileError(path, f, "missing array")
                continue
            try:
                arrays[f] = npz[f]
            except Exception as e:  # noqa: BLE001 - truncated or corrupt member
                raise ProblemFileError(path, f, f"cannot be read ({e})") from None
        name, meta = path.stem, {}
        if "meta_json" in npz.files:
            try:
                header = json.loads(str(npz["meta_json"].reshape(-1)[0]))
                name = str(header.get("name", name))
                meta = dict(header.get("meta", {}))
            except Exception as e:  # noqa: BLE001
                raise ProblemFileError(path, "meta_json", f"unreadable ({e})") from None
    if "pose_valid" not in arrays:
        arrays["pose_valid"] = np.ones(arrays["landing"].shape[:1], dtype=bool)
    absent = [f for f in _GEOMETRY if f not in arrays]
    if absent:
        if len(absent) < len(_GEOMETRY):
            raise ProblemFileError(
                path, absent[0], "missing array (give all of the geometry or none)"
            )
        arrays.update(_no_geometry(arrays["robustness"].shape))
        meta = {**meta, "geometry": False}
    problem = Problem(name=name, meta=meta, **arrays)
    problem.validate(path)
    return problem


# -------------------------------------------------------------------------- batches


@dataclasses.dataclass(frozen=True, eq=False)
class ProblemBatch:
    """Several problems padded to common T, P and K (SPEC §1: padding is masked).

    Only the arrays the bandit engine needs are kept; geometry stays in the
    individual :class:`Problem` objects.
    """

    names: tuple[str, ...]  # [O]
    landing: np.ndarray  # [O, P] float32, 0 on padded poses
    topple: np.ndarray  # [O, P, P] float32, padded rows are identity
    robustness: np.ndarray  # [O, T, P, K] float32, 0 on padding
    prior: np.ndarray  # [O, T, P, K] float32, 0 on padding
    valid: np.ndarray  # [O, T, P, K] bool
    pose_valid: np.ndarray  # [O, P] bool

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(O, T, P, K)."""
        return tuple(self.robustness.shape)  # type: ignore[return-value]


def stack(
    problems: Sequence[Problem],
    num_poses: int | None = None,
    num_grasps: int | None = None,
    num_trials: int | None = None,
) -> ProblemBatch:
    """Pad problems to common (T, P, K) and stack them on a leading object axis.

    ``num_trials`` may also cut every problem to its first trials (all problems
    must hold at least that many). Padded poses land with probability 0 and their
    topple row is the identity; padded grasp slots are invalid with p = q = 0.
    """
    if not problems:
        raise ValueError("stack() needs at least one problem")
    t_min = min(pb.num_trials for pb in problems)
    T = t_min if num_trials is None else num_trials
    if T > t_min:
        short = min(problems, key=lambda pb: pb.num_trials)
        raise ValueError(
            f"problem '{short.name}' has {short.num_trials} trials, {T} were asked for"
        )
    P = max(pb.num_poses for pb in problems) if num_poses is None else num_poses
    K = max(pb.num_grasps for pb in problems) if num_grasps is None else num_grasps
    O = len(problems)  # noqa: E741
    landing = np.zeros((O, P), np.float32)
    topple = np.tile(np.eye(P, dtype=np.float32), (O, 1, 1))
    rob = np.zeros((O, T, P, K), np.float32)
    prior = np.zeros((O, T, P, K), np.float32)
    valid = np.zeros((O, T, P, K), bool)
    pose_valid = np.zeros((O, P), bool)
    for o, pb in enumerate(problems):
        p, k = pb.num_poses, pb.num_grasps
        if p > P or k > K:
            raise ValueError(
                f"problem '{pb.name}' has P={p}, K={k}; cannot pad to P={P}, K={K}"
            )
        landing[o, :p] = pb.landing
        topple[o, :p, :p] = np.where(pb.pose_valid[:, None], pb.topple, np.eye(p))
        rob[o, :, :p, :k] = pb.robustness[:T]
        prior[o, :, :p, :k] = pb.prior[:T]
        valid[o, :, :p, :k] = pb.valid[:T]
        pose_valid[o, :p] = pb.pose_valid
    rob = np.where(valid, rob, 0.0).astype(np.float32)
    prior = np.where(valid, prior, 0.0).astype(np.float32)
    return ProblemBatch(
        names=tuple(pb.name for pb in problems),
        landing=landing,
        topple=topple,
        robustness=rob,
        prior=prior,
        valid=valid,
        pose_valid=pose_valid,
    )
