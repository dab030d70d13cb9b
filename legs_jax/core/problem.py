"""The problem of one object, its file format, and batches of problems.

A problem is everything the bandit environment needs about one object: where a drop
lands, where a failed grasp topples it, and for each of T reservoirs of K grasps per
pose the ground-truth success probability and the prior quality. It is stored as one
``.npz`` file whose arrays carry the names below. ``load`` validates every array and
refuses a bad file with a :class:`ProblemFileError` naming the file and the field.

Dimension letters: O objects, T trials (reservoirs), P poses, K grasps per pose.

Why one file: it is the only reader and writer of the problem format. The fields,
their validation, the compact encoding, the header peek and the batches all follow
the one list of arrays above, so a change to the format is made here and nowhere
else.
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
    "array_digests",
    "peek",
    "save_compact",
    "FORMAT_VERSION",
    "Problem",
    "ProblemBatch",
    "ProblemFileError",
    "load",
    "save",
    "stack",
    "unlearnable_poses",
    "describe_unlearnable",
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
    """One object after precompute. All arrays are NumPy arrays.

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


def unlearnable_poses(pb: Problem) -> list[dict[str, Any]]:
    """The real poses in which no method can learn anything, one dict each.

    A pose is listed when in some trial none of its grasps can succeed (no valid
    grasp, or every valid grasp has ground truth p = 0): every attempt there fails.
    When a failed grasp also always leaves the object where it was (``topple[s, s]
    = 1``, common for flat poses) the pose cannot be left at all in those trials:
    a rollout that lands there stays for the rest of its horizon, whatever the
    method does. Keys: ``pose``, ``landing`` (λ_s), ``trials_without_success``
    (trials whose reservoir of the pose has no grasp with p > 0), ``num_trials``,
    ``cannot_leave`` (a failure never moves the object), ``trapped_trials``
    (trials in which the pose cannot be left).
    """
    pstar = pb.p_star()  # [T, P]
    out = []
    for s in np.flatnonzero(pb.pose_valid):
        dead = pstar[:, s] <= 0.0
        if not dead.any():
            continue
        stuck = bool(pb.topple[s, s] >= 1.0 - _SUM_TOL)
        out.append(
            {
                "pose": int(s),
                "landing": float(pb.landing[s]),
                "trials_without_success": int(dead.sum()),
                "num_trials": int(pb.num_trials),
                "cannot_leave": stuck,
                "trapped_trials": int(dead.sum()) if stuck else 0,
            }
        )
    return out


def describe_unlearnable(flags: Sequence[dict[str, Any]]) -> list[str]:
    """One sentence a pose for :func:`unlearnable_poses`'s list."""
    lines = []
    for f in flags:
        line = (
            f"pose {f['pose']} (landing probability {f['landing']:.3f}) has no grasp "
            f"that can succeed in {f['trials_without_success']} of "
            f"{f['num_trials']} trial(s)"
        )
        if f["trapped_trials"]:
            line += (
                " and a failed grasp never moves it: a rollout that lands there is "
                "stuck for the rest of its horizon"
            )
        lines.append(line)
    return lines


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
    return _write_members(path, members, header)


def _write_members(
    path: Path, members: list[tuple[str, bytes]], header: dict[str, Any]
) -> Path:
    """Write ``members`` and the JSON ``header`` as a deterministic ``.npz``."""
    text = json.dumps(header, sort_keys=True)
    members = [*members, ("meta_json.npy", _npy_bytes(np.array(text)))]

    def write(fh) -> None:
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in members:
                info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                z.writestr(info, data, compresslevel=6)

    return atomic_write(path, write)


# ------------------------------------------------------------ the compact encoding
# A compact problem file (the shipped problem set, ``data/problemset/``) stores
# the same problem in fewer bytes, and ``load`` decodes it to the arrays above:
#
# - ``robustness_count`` [T, P, K] uint8: p = count / ``samples`` exactly as the
#   build computes it (the fraction of ``samples`` perturbed executions that
#   succeed: float64 division, then float32);
# - ``prior_u16`` [T, P, K] uint16: q quantised to k / 65535 (float64 division,
#   then float32): a shipped problem *is* these values, and results made from it
#   are made from exactly them;
# - the grasp geometry of the first ``geometry_trials`` trials only (the others
#   load as zeros), or none.
#
# Its header records ``encoding`` = ``COMPACT`` with ``samples`` and
# ``geometry_trials``.
COMPACT = "compact-1"
PRIOR_LEVELS = 65535
_COMPACT_MEMBERS = ("robustness_count", "prior_u16")


def quantize_prior(prior: np.ndarray) -> np.ndarray:
    """q as the compact encoding stores it: uint16 levels k / 65535."""
    q = np.clip(np.asarray(prior, np.float64), 0.0, 1.0)
    return np.rint(q * PRIOR_LEVELS).astype(np.uint16)


def dequantize_prior(levels: np.ndarray) -> np.ndarray:
    """[...] uint16 levels -> float32 q = k / 65535."""
    return (levels.astype(np.float64) / PRIOR_LEVELS).astype(np.float32)


def robustness_from_counts(count: np.ndarray, samples: int) -> np.ndarray:
    """[...] success counts of ``samples`` executions -> float32 p."""
    return (count.astype(np.float64) / float(samples)).astype(np.float32)


def save_compact(
    problem: Problem,
    path: str | os.PathLike,
    *,
    samples: int,
    geometry_trials: int = 0,
) -> Path:
    """Write ``problem`` in the compact encoding (above), atomically and
    byte-for-byte deterministically.

    ``samples``: the number of perturbed executions behind each p; every p must be
    a count of them (else :class:`ProblemFileError`). q is quantised to 16 bits:
    ``load`` returns the quantised values. ``geometry_trials``: keep the grasp
    geometry of that many leading trials (the rest load as zeros; pose transforms
    are always kept).
    """
    path = Path(path)
    problem.validate(path)
    rob = np.asarray(problem.robustness)
    count = np.rint(rob.astype(np.float64) * samples)
    if count.min() < 0 or count.max() > 255 or samples > 255:
        raise ProblemFileError(path, "robustness", "counts do not fit in uint8")
    count = count.astype(np.uint8)
    if not np.array_equal(robustness_from_counts(count, samples), rob):
        raise ProblemFileError(
            path, "robustness", f"values are not counts of {samples} executions"
        )
    T = problem.num_trials
    g = max(0, min(int(geometry_trials), T))
    members: list[tuple[str, bytes]] = [
        ("landing.npy", _npy_bytes(problem.landing)),
        ("topple.npy", _npy_bytes(problem.topple)),
        ("robustness_count.npy", _npy_bytes(count)),
        ("prior_u16.npy", _npy_bytes(quantize_prior(problem.prior))),
        ("valid.npy", _npy_bytes(problem.valid)),
        ("pose_transform.npy", _npy_bytes(problem.pose_transform)),
        ("pose_valid.npy", _npy_bytes(problem.pose_valid)),
    ]
    if g:
        for f in _GEOMETRY:
            if f != "pose_transform":
                members.append((f + ".npy", _npy_bytes(getattr(problem, f)[:g])))
    meta = {k: v for k, v in problem.meta.items() if k != "geometry"}
    header = {
        "format_version": FORMAT_VERSION,
        "name": problem.name,
        "meta": meta,
        "encoding": COMPACT,
        "samples": int(samples),
        "geometry_trials": g,
    }
    return _write_members(path, members, header)


def array_digests(problem: Problem) -> dict[str, str]:
    """SHA-256 of each array the bandit engine reads (dtype, shape and bytes):
    what names the arrays in which two problem files differ."""
    import hashlib

    out = {}
    for f in ("landing", "topple", "robustness", "prior", "valid", "pose_valid"):
        a = np.ascontiguousarray(getattr(problem, f))
        h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
        out[f] = h.hexdigest()
    return out


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
    ``robustness``). A file without a header (``meta_json``, as an abstract
    problem written with NumPy may be) has the file's stem as its name and an
    empty meta, as :func:`load` gives it. Raises :class:`ProblemFileError`,
    naming the file and the field, for an unreadable file."""
    path = Path(path)
    shapes = {}
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
            for field, members in (
                ("landing", ("landing",)),
                ("robustness", ("robustness", "robustness_count")),
            ):
                member = next((m for m in members if m + ".npy" in names), None)
                if member is None:
                    raise ProblemFileError(path, field, "missing array")
                with z.open(member + ".npy") as fh:
                    shapes[field] = tuple(_npy_shape(fh))
            raw = z.read("meta_json.npy") if "meta_json.npy" in names else None
    except ProblemFileError:
        raise
    except Exception as e:  # noqa: BLE001 - any unreadable file is refused alike
        raise ProblemFileError(
            path, "<file>", f"not a readable .npz file ({e})"
        ) from None
    header: dict[str, Any] = {}
    if raw is not None:
        try:
            arr = np.load(io.BytesIO(raw), allow_pickle=False)
            header = dict(json.loads(str(arr.reshape(-1)[0])))
        except Exception as e:  # noqa: BLE001
            raise ProblemFileError(path, "meta_json", f"unreadable ({e})") from None
    return {
        "name": header.get("name", path.stem),
        "meta": dict(header.get("meta", {})),
        "shapes": shapes,
    }


def _npy_shape(fh) -> tuple[int, ...]:
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _, _ = np.lib.format.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, _, _ = np.lib.format.read_array_header_2_0(fh)
    else:
        raise ValueError(f"unsupported .npy version {version}")
    return shape


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
        header: dict[str, Any] = {}
        if "meta_json" in npz.files:
            try:
                header = dict(json.loads(str(npz["meta_json"].reshape(-1)[0])))
            except Exception as e:  # noqa: BLE001
                raise ProblemFileError(path, "meta_json", f"unreadable ({e})") from None
        name = str(header.get("name", path.stem))
        meta = dict(header.get("meta", {}))
        compact = header.get("encoding") == COMPACT
        if header.get("encoding") not in (None, COMPACT):
            raise ProblemFileError(
                path, "meta_json", f"unknown encoding {header.get('encoding')!r}"
            )

        def read(f: str) -> np.ndarray:
            try:
                return npz[f]
            except Exception as e:  # noqa: BLE001 - truncated or corrupt member
                raise ProblemFileError(path, f, f"cannot be read ({e})") from None

        arrays: dict[str, np.ndarray] = {}
        if compact:
            for f in _COMPACT_MEMBERS:
                if f not in npz.files:
                    raise ProblemFileError(path, f, "missing array")
            count, levels = read("robustness_count"), read("prior_u16")
            if count.dtype != np.uint8 or levels.dtype != np.uint16:
                raise ProblemFileError(
                    path, "robustness_count", "expected uint8 counts, uint16 levels"
                )
            samples = header.get("samples")
            if not isinstance(samples, int) or not 0 < samples <= 255:
                raise ProblemFileError(path, "meta_json", "bad 'samples'")
            if count.max(initial=0) > samples:
                raise ProblemFileError(
                    path, "robustness_count", f"a count exceeds {samples} samples"
                )
            arrays["robustness"] = robustness_from_counts(count, samples)
            arrays["prior"] = dequantize_prior(levels)
        for f in _ARRAY_FIELDS:
            if f in arrays:
                continue
            if f not in npz.files:
                if f in _REQUIRED:
                    raise ProblemFileError(path, f, "missing array")
                continue
            arrays[f] = read(f)
    if compact:
        T, P, K = arrays["robustness"].shape
        g = int(header.get("geometry_trials", 0))
        full = _no_geometry((T, P, K))
        for f in _GEOMETRY:
            if f == "pose_transform":
                continue
            if f in arrays:
                if arrays[f].shape[:1] != (g,):
                    raise ProblemFileError(
                        path, f, f"expected the geometry of {g} trials"
                    )
                full[f][:g] = arrays[f]
            arrays[f] = full[f]
        if "pose_transform" not in arrays:
            arrays["pose_transform"] = full["pose_transform"]
        meta = {**meta, "geometry_trials": g}
        if g == 0:
            meta["geometry"] = False
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
    """Several problems padded to common T, P and K (padding is masked).

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
