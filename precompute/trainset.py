"""Training examples for the learned prior: generated objects, labelled by the same
physics as the evaluation problems.

An object (:mod:`precompute.shapes`) is posed as an evaluation object is (stable
poses, λ ≥ ``poses.LANDING_THRESHOLD``, :mod:`precompute.poses`), except that
equivalent resting facets are not merged (the merge test costs seconds an object and
only matters for the landing probabilities); of its poses the ``max_poses`` most
likely are used. Per pose: one reservoir of up to ``grasps``
antipodal grasps (:func:`precompute.grasps.sample_reservoir`), each labelled with its
robustness p from ``samples`` perturbed executions
(:func:`precompute.grasps.robustness`, the evaluation problems' perturbation model),
and one noisy depth image (:func:`precompute.depth.observe`).

Randomness: ``SeedSequence([seed, STREAM_TRAIN, object, pose, stream])`` with
streams 1 (grasps), 2 (perturbations), 3 (sensor noise); nothing depends on the
number of processes.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import depth as _depth
from . import grasps as G
from . import poses as _poses
from .raycast import RayCaster, face_pad_normals
from .shapes import Shape

__all__ = ["STREAM_TRAIN", "PoseExamples", "label_shape"]

STREAM_TRAIN = 12


@dataclasses.dataclass(frozen=True, eq=False)
class PoseExamples:
    """The labelled grasps of one pose of one generated object."""

    obj: int  # object index
    pose: int
    image: np.ndarray  # [H, W] float32 noisy resized depth image
    u0: float  # the image's sensor offset (depth.DepthImage)
    v0: float
    scale: int
    center: np.ndarray  # [N, 3] float32 jaw centres (pose frame)
    axis: np.ndarray  # [N, 3] float32 jaw axes
    p: np.ndarray  # [N] float32 robustness

    def depth_image(self) -> _depth.DepthImage:
        return _depth.DepthImage(self.image, self.u0, self.v0, self.scale)


def _rng(seed: int, obj: int, pose: int, stream: int) -> np.random.Generator:
    ss = np.random.SeedSequence([seed, STREAM_TRAIN, obj, pose, stream])
    return np.random.Generator(np.random.PCG64(ss))


def _rotate(points: np.ndarray, rot: np.ndarray) -> np.ndarray:
    x, y, z = points[:, 0:1], points[:, 1:2], points[:, 2:3]
    return x * rot[:, 0] + y * rot[:, 1] + z * rot[:, 2]


def label_shape(
    shape: Shape,
    *,
    seed: int,
    grasps: int,
    samples: int = G.SAMPLES,
    max_poses: int = 4,
) -> list[PoseExamples]:
    """The labelled poses of one generated object (module docstring)."""
    v, f = shape.vertices, shape.faces
    com = np.asarray(shape.trimesh().center_mass, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):  # sliver hull triangles
        hull = _poses.hull_model(v, f, com)
        sp = _poses.stable_poses(hull, v, f, merge=False)
    pad = face_pad_normals(v, f, G.PAD_RADIUS)
    out = []
    for s in range(min(max_poses, len(sp.landing))):
        tf = sp.transforms[s]
        posed = _rotate(v, tf[:3, :3]) + tf[:3, 3]
        caster = RayCaster(
            posed, f, pad_normals={G.PAD_RADIUS: _rotate(pad, tf[:3, :3])}
        )
        hmap = G.height_map(caster)
        res = G.sample_reservoir(caster, hmap, grasps, _rng(seed, shape.index, s, 1))
        idx = np.flatnonzero(res.valid)
        if len(idx) == 0:
            continue
        dxy, dyaw, mu = G.perturbations(_rng(seed, shape.index, s, 2), grasps, samples)
        p = G.robustness(
            caster, hmap, res.center[idx], res.axis[idx], dxy[idx], dyaw[idx], mu[idx]
        )
        img = _depth.observe(caster, _rng(seed, shape.index, s, 3))
        out.append(
            PoseExamples(
                obj=shape.index,
                pose=s,
                image=img.depth,
                u0=img.u0,
                v0=img.v0,
                scale=img.scale,
                center=res.center[idx].astype(np.float32),
                axis=res.axis[idx].astype(np.float32),
                p=p.astype(np.float32),
            )
        )
    return out
