"""Overhead depth images of a posed object, with a sensor's noise.

Camera (the learned prior's only view of an object)
---------------------------------------------------
A pinhole camera ``HEIGHT`` = 0.7 m above the table, looking straight down at the
origin of the pose frame (where the centre of mass stands), with a Primesense-like
640 × 480 sensor: fx = fy = ``FOCAL`` = 525 px, principal point (319.5, 239.5). Image
axes: u to the right is +x, v down is -y; a pixel's value is the depth along the
optical axis, ``HEIGHT`` - z of the first surface its ray meets (the table, z = 0,
where the ray meets no object). At the table one pixel is 1.33 mm. Only a window of
the sensor around the object is rendered: the object's footprint plus
``MARGIN_PX`` pixels on every side (room for a grasp crop); one Embree ray per pixel
through the pixel's centre.

GQ-CNN (BerkeleyAutomation/gqcnn; Dex-Net 2.0, RSS 2017) cuts a 96 × 96 pixel crop
around a grasp and resizes it to 32 × 32. Here the window is resized once, by
averaging blocks of ``DOWNSAMPLE`` × ``DOWNSAMPLE`` = 3 × 3 pixels (4 mm at the
table), and crops are cut from the resized image (:mod:`precompute.gqcnn`).

Sensor noise (Dex-Net 2.0's, gqcnn's training configuration: ``gamma_shape`` 1000,
``gaussian_process_sigma`` 0.005, ``gaussian_process_scaling_factor`` 4), applied to
the resized image:

- multiplicative: the whole image times one Gamma(shape 1000, scale 1/1000) draw
  (mean 1, standard deviation 3.2 %);
- correlated Gaussian: N(0, 5 mm) on a grid of every 4th pixel, upsampled to the
  image by cubic-spline interpolation and added.

gqcnn adds the correlated noise to half of its training images; a sensor has it
always, and so does every image here, for training and for scoring alike. Each
image's noise comes from the ``Generator`` passed in (seeded by the caller).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .raycast import RayCaster

__all__ = [
    "HEIGHT",
    "FOCAL",
    "CENTER",
    "DOWNSAMPLE",
    "MARGIN_PX",
    "GAMMA_SHAPE",
    "GP_SIGMA",
    "GP_STEP",
    "DepthImage",
    "camera_params",
    "render",
    "downsample",
    "add_noise",
    "observe",
    "project",
]

HEIGHT = 0.7
FOCAL = 525.0
CENTER = (319.5, 239.5)  # (cx, cy) of a 640 x 480 sensor
DOWNSAMPLE = 3
MARGIN_PX = 96  # native pixels around the footprint (a rotated 96-px crop fits)
GAMMA_SHAPE = 1000.0
GP_SIGMA = 0.005
GP_STEP = 4  # resized pixels between correlated-noise grid points


def camera_params() -> dict:
    """Every constant of the camera and the noise (for hashes and model cards)."""
    return {
        "height_m": HEIGHT,
        "fx": FOCAL,
        "fy": FOCAL,
        "cx": CENTER[0],
        "cy": CENTER[1],
        "sensor": [640, 480],
        "downsample": DOWNSAMPLE,
        "margin_px": MARGIN_PX,
        "gamma_shape": GAMMA_SHAPE,
        "gp_sigma_m": GP_SIGMA,
        "gp_step_px": GP_STEP,
    }


@dataclasses.dataclass(frozen=True, eq=False)
class DepthImage:
    """A window of the sensor: ``depth[i, j]`` is pixel (u0 + j·step', v0 + i·step')
    where the pixel size is ``scale`` sensor pixels (1 native, 3 resized)."""

    depth: np.ndarray  # [H, W] float32, metres along the optical axis
    u0: float  # sensor u of the centre of pixel [0, 0]
    v0: float  # sensor v of the centre of pixel [0, 0]
    scale: int  # sensor pixels per image pixel

    def pixel_of(self, uv: np.ndarray) -> np.ndarray:
        """[..., 2] (column, row) image coordinates of sensor points uv [..., 2]."""
        uv = np.asarray(uv, np.float64)
        return np.stack(
            [(uv[..., 0] - self.u0) / self.scale, (uv[..., 1] - self.v0) / self.scale],
            axis=-1,
        )


def project(points: np.ndarray) -> np.ndarray:
    """[..., 2] sensor (u, v) of pose-frame points [..., 3]."""
    p = np.asarray(points, np.float64)
    z = HEIGHT - p[..., 2]
    return np.stack(
        [CENTER[0] + FOCAL * p[..., 0] / z, CENTER[1] - FOCAL * p[..., 1] / z], axis=-1
    )


def render(caster: RayCaster, margin_px: int = MARGIN_PX) -> DepthImage:
    """The noiseless depth image (native pixels) of the posed mesh of ``caster``
    (pose frame: table z = 0), over its footprint plus ``margin_px`` pixels. The
    window's size is a multiple of :data:`DOWNSAMPLE`."""
    v = caster.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (0, hi[2])]
    )
    uv = project(corners)
    u_lo = np.floor(uv[:, 0].min() - CENTER[0]) - margin_px
    v_lo = np.floor(uv[:, 1].min() - CENTER[1]) - margin_px
    u_hi = np.ceil(uv[:, 0].max() - CENTER[0]) + margin_px
    v_hi = np.ceil(uv[:, 1].max() - CENTER[1]) + margin_px
    w = int(np.ceil((u_hi - u_lo + 1) / DOWNSAMPLE)) * DOWNSAMPLE
    h = int(np.ceil((v_hi - v_lo + 1) / DOWNSAMPLE)) * DOWNSAMPLE
    u0, v0 = CENTER[0] + u_lo, CENTER[1] + v_lo
    uu, vv = np.meshgrid(u0 + np.arange(w), v0 + np.arange(h))
    dirs = np.stack(
        [(uu - CENTER[0]) / FOCAL, -(vv - CENTER[1]) / FOCAL, -np.ones_like(uu)],
        axis=-1,
    ).reshape(-1, 3)
    origins = np.broadcast_to(np.array([0.0, 0.0, HEIGHT]), dirs.shape)
    t, _ = caster.cast_raw(origins, dirs)  # the direction's z is -1: t is depth
    depth = np.where(np.isfinite(t), t, np.float32(HEIGHT)).astype(np.float32)
    depth = np.minimum(depth, np.float32(HEIGHT))  # nothing below the table
    return DepthImage(depth.reshape(h, w), float(u0), float(v0), 1)


def downsample(image: DepthImage, factor: int = DOWNSAMPLE) -> DepthImage:
    """Average blocks of ``factor`` × ``factor`` pixels (GQ-CNN's 96 → 32 resize)."""
    d = image.depth
    h, w = d.shape[0] // factor, d.shape[1] // factor
    blocks = d[: h * factor, : w * factor].reshape(h, factor, w, factor)
    mean = blocks.astype(np.float64).mean(axis=(1, 3)).astype(np.float32)
    off = (factor - 1) / 2.0  # centre of a block, in native pixels
    return DepthImage(
        mean,
        image.u0 + off * image.scale,
        image.v0 + off * image.scale,
        image.scale * factor,
    )


def add_noise(image: DepthImage, rng: np.random.Generator) -> DepthImage:
    """The image with Dex-Net 2.0's sensor noise (module docstring), from ``rng``."""
    from scipy import ndimage

    d = image.depth.astype(np.float64)
    h, w = d.shape
    gain = rng.gamma(GAMMA_SHAPE, 1.0 / GAMMA_SHAPE)
    gh, gw = -(-h // GP_STEP) + 1, -(-w // GP_STEP) + 1
    grid = rng.normal(0.0, GP_SIGMA, (gh, gw))
    rows = np.arange(h) / GP_STEP
    cols = np.arange(w) / GP_STEP
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    smooth = ndimage.map_coordinates(grid, [rr, cc], order=3, mode="nearest")
    noisy = (d * gain + smooth).astype(np.float32)
    return DepthImage(noisy, image.u0, image.v0, image.scale)


def observe(caster: RayCaster, rng: np.random.Generator | None) -> DepthImage:
    """What the prior sees of a pose: rendered, resized, noised (no noise when
    ``rng`` is None)."""
    img = downsample(render(caster))
    return img if rng is None else add_noise(img, rng)
