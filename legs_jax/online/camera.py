"""Pinhole camera: intrinsics, the camera's pose over the table, deprojection.

Frames (metres): the camera frame has x right, y down, z along the optical axis;
the table frame has the table plane at z = 0, z up. ``camera_pose`` is the 4×4
rigid transform camera → table. The default camera looks straight down from
``DEFAULT_HEIGHT`` above the table origin, so that a rotation about its optical
axis is a yaw on the table.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from legs_jax.online.errors import InputError

__all__ = [
    "DEFAULT_HEIGHT",
    "Intrinsics",
    "default_camera_pose",
    "deproject",
    "check_depth",
]

DEFAULT_HEIGHT = 0.7


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a depth image of ``width`` × ``height`` pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_any(cls, value) -> Intrinsics:
        """From an :class:`Intrinsics` or a mapping with the six fields."""
        if isinstance(value, Intrinsics):
            out = value
        elif isinstance(value, dict):
            missing = [f.name for f in dataclasses.fields(cls) if f.name not in value]
            if missing:
                raise InputError(f"intrinsics lack {', '.join(missing)}")
            try:
                out = cls(
                    fx=float(value["fx"]),
                    fy=float(value["fy"]),
                    cx=float(value["cx"]),
                    cy=float(value["cy"]),
                    width=int(value["width"]),
                    height=int(value["height"]),
                )
            except (TypeError, ValueError) as e:
                raise InputError(f"intrinsics must be numbers: {e}") from None
        else:
            raise InputError(
                "intrinsics must be a mapping with fx, fy, cx, cy, width, height"
            )
        vals = (out.fx, out.fy, out.cx, out.cy)
        if not all(np.isfinite(vals)) or out.fx <= 0 or out.fy <= 0:
            raise InputError(f"intrinsics must be finite with fx, fy > 0, got {out}")
        if out.width < 1 or out.height < 1:
            raise InputError(f"image size must be positive, got {out}")
        return out

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def project(self, points: np.ndarray) -> np.ndarray:
        """[N, 2] pixel (u, v) of camera-frame points [N, 3]."""
        p = np.asarray(points, np.float64)
        return np.stack(
            [
                self.fx * p[:, 0] / p[:, 2] + self.cx,
                self.fy * p[:, 1] / p[:, 2] + self.cy,
            ],
            axis=1,
        )

    def rays(self) -> np.ndarray:
        """[H, W, 3] direction of each pixel's ray (z = 1), camera frame
        (computed once per intrinsics; read-only)."""
        return _rays(self)


@functools.lru_cache(maxsize=8)
def _rays(intr: Intrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    out = np.stack(
        [(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(u.shape)],
        axis=-1,
    )
    out.flags.writeable = False
    return out


def default_camera_pose(height: float = DEFAULT_HEIGHT) -> np.ndarray:
    """Camera → table for a camera straight above the table origin, looking down
    (camera x = table x, camera y = −table y)."""
    tf = np.eye(4)
    tf[:3, :3] = np.diag([1.0, -1.0, -1.0])
    tf[2, 3] = height
    return tf


def check_camera_pose(tf) -> np.ndarray:
    a = np.asarray(tf, np.float64)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise InputError("camera_pose must be a finite 4x4 matrix")
    r = a[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
        raise InputError(
            "camera_pose must be a rigid transform (rotation + translation)"
        )
    return a


def check_depth(depth, intr: Intrinsics) -> np.ndarray:
    """The depth image as float64 [H, W] metres (0 or NaN: no reading), or a clear
    error."""
    try:
        d = np.asarray(depth, np.float64)
    except (TypeError, ValueError):
        raise InputError("depth must be a 2-D array of numbers (metres)") from None
    if d.ndim != 2:
        raise InputError(f"depth must be a 2-D image, got shape {d.shape}")
    if d.shape != (intr.height, intr.width):
        raise InputError(
            f"depth image is {d.shape[1]}x{d.shape[0]} but the intrinsics say "
            f"{intr.width}x{intr.height}"
        )
    if np.any(np.isinf(d)):
        raise InputError("depth holds infinite values")
    good = np.isfinite(d) & (d > 0)
    if not good.any():
        raise InputError("depth image is empty (every pixel is 0 or NaN)")
    if good.mean() < 0.5:
        raise InputError(
            f"only {100 * good.mean():.0f}% of the depth pixels hold a reading; "
            "is this a depth image in metres?"
        )
    med = float(np.median(d[good]))
    if not 0.05 <= med <= 5.0:
        raise InputError(
            f"median depth {med:g} is not a distance in metres (expected 0.05-5)"
        )
    return np.where(good, d, np.nan)


def deproject(depth: np.ndarray, intr: Intrinsics, camera_pose: np.ndarray):
    """Table-frame points [H, W, 3] of every pixel (NaN where there is no reading)."""
    pts = intr.rays() * depth[..., None]
    return pts @ camera_pose[:3, :3].T + camera_pose[:3, 3]
