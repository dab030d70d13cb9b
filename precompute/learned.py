"""The learned prior q of a problem: the shipped network scores every reservoir grasp
from the depth image of its pose alone.

Per pose the posed mesh is rendered once (:func:`precompute.depth.render`, resized);
each trial's reservoir is seen in its own noisy copy of that image (sensor noise
from the stream ``SeedSequence([seed, object_key, pose, trial, STREAM_DEPTH])``), and
q = sigmoid(network(crop, grasp depth)) for each valid slot (0 in padding slots).
Nothing here reads p, the perturbations or the mesh beyond its rendered image.

The weights are ``precompute/prior_weights/weights.npz`` (the shipped ones) unless
a build names others (``--prior-weights PATH``, as ``python -m precompute
train-prior`` writes them); a problem file records which (``meta["prior_weights"]``:
the path as given and the SHA-256), and the build hash includes the SHA-256, so
other weights rebuild the problems. JAX is imported
only when the learned prior is used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import depth as _depth
from .errors import PrecomputeError
from .gqcnn import CLIP, DEPTH_SCALE, Scorer, file_sha256, load_weights

__all__ = [
    "PRIORS",
    "VERSION",
    "weights_path",
    "available",
    "default_prior",
    "prior_params",
    "score_reservoirs",
    "scorer",
]

PRIORS = ("learned", "synthetic")
VERSION = "1"  # bumped when scoring changes its output for the same weights

_SCORERS: dict = {}
_PARAMS: dict = {}


def weights_path() -> Path:
    """The shipped weights file."""
    return Path(__file__).resolve().parent / "prior_weights" / "weights.npz"


def _path_of(weights: str | Path | None) -> Path:
    """The weights file: ``weights`` when given (``--prior-weights``), else the
    shipped one."""
    return weights_path() if weights is None else Path(weights)


#: How meta names the shipped weights (``meta["prior_weights"]["path"]``).
SHIPPED_LABEL = "precompute/prior_weights/weights.npz"


def available() -> bool:
    return weights_path().is_file()


def default_prior() -> str:
    """ "learned" when weights are shipped, else "synthetic"."""
    return "learned" if available() else "synthetic"


def _missing(weights=None) -> PrecomputeError:
    if weights is not None:
        return PrecomputeError(
            f"{weights}: no such prior weights file (python -m precompute "
            "train-prior writes runs/prior/weights.npz)"
        )
    return PrecomputeError(
        "the learned prior has no weights yet (precompute/prior_weights/weights.npz "
        "is missing): train them with `python -m precompute train-prior`, or build "
        "with --prior synthetic"
    )


def prior_params(weights: str | Path | None = None) -> dict:
    """What q depends on besides the image and the grasps (meta and build hash);
    ``weights``: a weights file other than the shipped one."""
    path = _path_of(weights)
    if not path.is_file():
        raise _missing(weights)
    key = (str(path.resolve()), path.stat().st_mtime_ns, path.stat().st_size)
    if key not in _PARAMS:
        if weights is not None:
            load_weights(path)  # a clear error for a file that is not weights
        _PARAMS[key] = {
            "model": "learned GQ-CNN-style network (precompute/gqcnn.py)",
            "weights_sha256": file_sha256(path),
            "camera": _depth.camera_params(),
            "clip_m": CLIP,
            "depth_scale_m": DEPTH_SCALE,
            "version": VERSION,
            "synthetic": False,
        }
    return dict(_PARAMS[key])


def weights_meta(weights: str | Path | None = None) -> dict:
    """``meta["prior_weights"]``: the weights file as given (the shipped one as
    :data:`SHIPPED_LABEL`) and its SHA-256."""
    sha = prior_params(weights)["weights_sha256"]
    return {"path": SHIPPED_LABEL if weights is None else str(weights), "sha256": sha}


def scorer(weights: str | Path | None = None):
    """The network of the weights (default: the shipped ones), built once per
    weights file: ``scorer()(image, centers, axes) -> q``."""
    sha = prior_params(weights)["weights_sha256"]
    if sha not in _SCORERS:
        params, arch, _ = load_weights(_path_of(weights))
        _SCORERS.clear()
        _SCORERS[sha] = Scorer(params, arch)
    return _SCORERS[sha]


def score_reservoirs(caster, reservoirs, rngs, weights=None) -> np.ndarray:
    """[T, K] float32 q of the reservoirs of one pose (``caster``: the posed mesh),
    trial t seen through the noise of ``rngs[t]``; ``weights``: a weights file
    other than the shipped one."""
    net = scorer(weights)
    clean = _depth.downsample(_depth.render(caster))
    K = len(reservoirs[0].valid)
    out = np.zeros((len(reservoirs), K), np.float32)
    for t, (res, rng) in enumerate(zip(reservoirs, rngs, strict=True)):
        v = np.flatnonzero(res.valid)
        if len(v):
            img = _depth.add_noise(clean, rng)
            # the grasps as the problem file stores them (float32): q is a
            # function of the recorded grasp poses and the image alone
            c = res.center[v].astype(np.float32)
            a = res.axis[v].astype(np.float32)
            out[t, v] = net(img, c, a)
    return out
