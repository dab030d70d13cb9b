"""The learned prior's network: GQ-CNN-style grasp crops and a small flax CNN.

Input per grasp (as GQ-CNN's, BerkeleyAutomation/gqcnn; Dex-Net 2.0, RSS 2017)
------------------------------------------------------------------------------
- ``CROP`` × ``CROP`` = 32 × 32 pixels of the resized depth image
  (:mod:`precompute.depth`: 3 sensor pixels, 4 mm at the table, per pixel; so a
  96 × 96 sensor-pixel window, GQ-CNN's), centred on the projection of the jaw
  centre and turned so that the crop's columns run along the jaw axis (its image
  direction (a_x, -a_y)); bilinear samples, the image's edge beyond it;
- depths relative to the grasp: (pixel depth - grasp depth) clipped to
  ± ``CLIP`` = 8 cm, divided by ``DEPTH_SCALE`` = 3 cm, where the grasp depth is
  the jaw centre's depth along the optical axis (``depth.HEIGHT`` - c_z);
- the grasp depth itself, as (grasp depth - (``depth.HEIGHT`` - 3 cm)) / 3 cm.

A jaw axis and its opposite are the same grasp for this two-finger gripper; the
crop of one is the other's turned by 180°, and training shows the network both.

Network (flax ``linen``; the defaults of :class:`Arch`): the 32 × 32 crop as
16 × 16 × 4 (space to depth: each 2 × 2 block of pixels becomes 4 channels, so the
first 3 × 3 convolution sees 6 × 6 pixels with stride 2) - conv 3×3 (16) - ReLU -
2×2 max pool - conv 3×3 (32) - ReLU - pool - dense 64; the grasp depth through a
dense layer of 16 (GQ-CNN's pose branch); both joined, ReLU, dense 64, ReLU, one
logit; q = sigmoid(logit). About 43 k parameters. GQ-CNN's own first layer (conv
7×7 on the 32 × 32 crop, 64 filters) costs far more on a CPU: measured here, a
5×5 first convolution on the full crop scores about 6× fewer grasps per second
than the space-to-depth layer, which made the 10-minute scoring budget.

Weights are saved without pickle: an ``.npz`` of the flattened parameters
("params/Conv_0/kernel", ...) plus the architecture as a JSON string.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from legs_jax._files import sha256_file as file_sha256

from . import depth as _depth
from .errors import PrecomputeError

__all__ = [
    "CROP",
    "CLIP",
    "DEPTH_SCALE",
    "Arch",
    "make_model",
    "init_params",
    "crops",
    "grasp_inputs",
    "save_weights",
    "load_weights",
    "file_sha256",
    "Cropper",
    "Scorer",
]

CROP = 32
CLIP = 0.08
DEPTH_SCALE = 0.03
_Z_OFFSET = _depth.HEIGHT - 0.03
_BATCH = 256  # grasps per scoring call (padded; small batches stay in cache)
_PAD = 32  # image sides are padded up to a multiple of this (few compilations)


@dataclasses.dataclass(frozen=True)
class Arch:
    """The network's shape (saved with the weights)."""

    features: tuple[int, ...] = (16, 32)
    hidden: int = 64
    crop: int = CROP
    space_to_depth: int = 2

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @staticmethod
    def from_json(text: str) -> Arch:
        d = json.loads(text)
        return Arch(
            tuple(int(f) for f in d["features"]),
            int(d["hidden"]),
            int(d["crop"]),
            int(d["space_to_depth"]),
        )


def make_model(arch: Arch):
    """The flax module of ``arch``: (images [N, S, S, 1], z [N, 1]) -> logits [N]."""
    import flax.linen as nn
    import jax.numpy as jnp

    class GQCNN(nn.Module):
        @nn.compact
        def __call__(self, im, z):
            n, s, b = im.shape[0], arch.crop, arch.space_to_depth
            x = im.reshape(n, s // b, b, s // b, b, 1)
            x = x.transpose(0, 1, 3, 2, 4, 5).reshape(n, s // b, s // b, b * b)
            for f in arch.features:
                x = nn.relu(nn.Conv(f, (3, 3))(x))
                x = nn.max_pool(x, (2, 2), strides=(2, 2))
            x = nn.Dense(arch.hidden)(x.reshape(x.shape[0], -1))
            zz = nn.Dense(16)(z)
            h = nn.relu(jnp.concatenate([x, zz], axis=-1))
            h = nn.relu(nn.Dense(arch.hidden)(h))
            return nn.Dense(1)(h)[:, 0]

    return GQCNN()


def init_params(arch: Arch, rng_key):
    import jax.numpy as jnp

    s = arch.crop
    return make_model(arch).init(
        rng_key, jnp.zeros((1, s, s, 1), jnp.float32), jnp.zeros((1, 1), jnp.float32)
    )


def crops(image, pix, axis_uv, grasp_depth, size: int = CROP):
    """[N, size, size] network crops (JAX arrays; see the module docstring).

    image [H, W] (resized depth, metres); pix [N, 2] (column, row) of the jaw
    centres in ``image``; axis_uv [N, 2] unit jaw axes in image coordinates
    (u right, v down); grasp_depth [N] metres.
    """
    import jax.numpy as jnp

    h, w = image.shape
    off = jnp.arange(size, dtype=jnp.float32) - (size - 1) / 2.0
    ea = axis_uv  # along the jaw axis: the crop's columns
    ep = jnp.stack([-axis_uv[:, 1], axis_uv[:, 0]], axis=1)  # across it: rows
    col = (
        pix[:, None, None, 0]
        + off[None, None, :] * ea[:, None, None, 0]
        + off[None, :, None] * ep[:, None, None, 0]
    )
    row = (
        pix[:, None, None, 1]
        + off[None, None, :] * ea[:, None, None, 1]
        + off[None, :, None] * ep[:, None, None, 1]
    )
    col = jnp.clip(col, 0.0, w - 1.0)
    row = jnp.clip(row, 0.0, h - 1.0)
    c0 = jnp.clip(jnp.floor(col), 0, w - 2).astype(jnp.int32)
    r0 = jnp.clip(jnp.floor(row), 0, h - 2).astype(jnp.int32)
    fc = col - c0
    fr = row - r0
    flat = image.reshape(-1)
    i00 = r0 * w + c0
    v00, v01 = flat[i00], flat[i00 + 1]
    v10, v11 = flat[i00 + w], flat[i00 + w + 1]
    val = (v00 * (1 - fc) + v01 * fc) * (1 - fr) + (v10 * (1 - fc) + v11 * fc) * fr
    rel = jnp.clip(val - grasp_depth[:, None, None], -CLIP, CLIP)
    return rel / DEPTH_SCALE


def grasp_inputs(image: _depth.DepthImage, centers: np.ndarray, axes: np.ndarray):
    """(pix [N, 2], axis_uv [N, 2], grasp_depth [N]) float32 of grasps (pose-frame
    centres [N, 3] and unit horizontal axes [N, 3]) in ``image``."""
    c = np.asarray(centers, np.float64)
    a = np.asarray(axes, np.float64)
    pix = image.pixel_of(_depth.project(c))
    auv = np.stack([a[:, 0], -a[:, 1]], axis=1)
    auv /= np.maximum(np.linalg.norm(auv, axis=1, keepdims=True), 1e-12)
    gd = _depth.HEIGHT - c[:, 2]
    return pix.astype(np.float32), auv.astype(np.float32), gd.astype(np.float32)


def z_input(grasp_depth):
    """[N, 1] the network's grasp-depth input."""
    return ((grasp_depth - _Z_OFFSET) / DEPTH_SCALE)[:, None]


# ------------------------------------------------------------------- weights IO


def _flatten(tree, prefix=""):
    out = {}
    for k, v in tree.items():
        key = f"{prefix}/{k}" if prefix else str(k)
        if isinstance(v, dict) or hasattr(v, "items"):
            out.update(_flatten(dict(v), key))
        else:
            out[key] = np.asarray(v, np.float32)
    return out


def _unflatten(flat: dict):
    tree: dict = {}
    for key, v in flat.items():
        node = tree
        parts = key.split("/")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = v
    return tree


def save_weights(path: Path, params, arch: Arch, extra: dict | None = None) -> str:
    """Write the parameters and architecture to ``path`` (.npz, no pickle);
    returns the file's SHA-256."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {f"w:{k}": v for k, v in _flatten(dict(params)).items()}
    arrays["arch_json"] = np.array(arch.to_json())
    arrays["info_json"] = np.array(json.dumps(extra or {}, sort_keys=True))
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return file_sha256(path)


def load_weights(path: Path):
    """(params, arch, info) from a weights file, or a clear error."""
    path = Path(path)
    if not path.is_file():
        raise PrecomputeError(f"no prior weights at {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            arch = Arch.from_json(str(z["arch_json"]))
            info = json.loads(str(z["info_json"]))
            flat = {k[2:]: np.asarray(z[k]) for k in z.files if k.startswith("w:")}
    except Exception as e:  # noqa: BLE001 - any unreadable file is refused
        raise PrecomputeError(f"{path}: not a prior weights file ({e})") from None
    return _unflatten(flat), arch, info


# ---------------------------------------------------------------------- scoring


def _pad_image(d: np.ndarray) -> np.ndarray:
    hp = -(-d.shape[0] // _PAD) * _PAD
    wp = -(-d.shape[1] // _PAD) * _PAD
    return np.pad(d, ((0, hp - d.shape[0]), (0, wp - d.shape[1])), mode="edge")


def _batched(fn, image: _depth.DepthImage, centers, axes, out_dtype=np.float32):
    """fn(padded image, pix, axis_uv, grasp_depth) over fixed-size batches of the
    grasps (pose frame) seen in ``image``; results concatenated."""
    pix, auv, gd = grasp_inputs(image, centers, axes)
    padded = _pad_image(image.depth)
    n = len(pix)
    out = None
    for start in range(0, n, _BATCH):
        stop = min(n, start + _BATCH)
        m = stop - start
        sl = slice(start, stop)
        p = np.zeros((_BATCH, 2), np.float32)
        u = np.zeros((_BATCH, 2), np.float32)
        g = np.full(_BATCH, _depth.HEIGHT, np.float32)
        u[:, 0] = 1.0
        p[:m], u[:m], g[:m] = pix[sl], auv[sl], gd[sl]
        res = np.asarray(fn(padded, p, u, g))[:m]
        if out is None:
            out = np.zeros((n, *res.shape[1:]), out_dtype)
        out[sl] = res
    if out is None:
        out = np.zeros((0,), out_dtype)
    return out


class Cropper:
    """Network inputs (crops [N, S, S] and z [N]) of grasps seen in an image."""

    def __init__(self, size: int = CROP):
        import jax

        self.size = size
        self._fn = jax.jit(lambda im, p, u, g: crops(im, p, u, g, size))

    def __call__(self, image: _depth.DepthImage, centers, axes):
        x = _batched(self._fn, image, centers, axes)
        _, _, gd = grasp_inputs(image, centers, axes)
        return x, np.asarray(z_input(gd))[:, 0]


class Scorer:
    """q of grasps from a depth image and the grasps' poses alone, in batches of
    ``_BATCH`` grasps (padded, so that one compilation serves every call, and the
    images padded to a multiple of 32 pixels)."""

    def __init__(self, params, arch: Arch):
        import jax
        import jax.numpy as jnp

        self.arch = arch
        self.params = jax.tree_util.tree_map(jnp.asarray, params)
        model = make_model(arch)

        def logits(image, pix, auv, gd):
            x = crops(image, pix, auv, gd, arch.crop)[..., None]
            return model.apply(self.params, x, z_input(gd))

        self._logits = jax.jit(logits)

    def logits(self, image: _depth.DepthImage, centers, axes) -> np.ndarray:
        """[N] float32 logits of grasps (pose frame) seen in ``image``."""
        return _batched(self._logits, image, centers, axes)

    def __call__(self, image: _depth.DepthImage, centers, axes) -> np.ndarray:
        """[N] float32 q in (0, 1)."""
        z = self.logits(image, centers, axes).astype(np.float64)
        return (1.0 / (1.0 + np.exp(-z))).astype(np.float32)
