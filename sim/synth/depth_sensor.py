"""Depth cameras for the synthetic world: what an active stereo or structured-light sensor
makes of the rendered depth.

Depth comes from a disparity d = f b / z (f the depth imager's focal length in pixels, b its
baseline), measured with an RMS error `disparity_noise_px` and reported in steps of
`disparity_step_px`, so the depth noise sigma_z = z^2 sigma_d / (f b) grows with the square of
the distance and so do the quantisation steps. Pixels get no depth (0) outside the sensor's
range, where the second viewpoint (projector or second imager, `baseline_m` along the camera's
x axis) cannot see the surface (occlusion shadows beside near objects), across depth edges
(the left-right consistency check of stereo sensors drops them), on dark surfaces (too little
of the projected pattern comes back) and on glossy ones (glare near normal incidence, random
dropouts elsewhere).

Figures (`SENSORS`):
- Intel RealSense D435 / D455: baseline 50 / 95 mm, depth field of view 87 x 58 deg, so
  f = 424 / tan(43.5 deg) = 447 px at 848x480; minimum depth 0.28 / 0.52 m at 1280x720; range
  to about 10 m; depth unit 1 mm (Intel RealSense D400 Series Datasheet, doc. 337029). Subpixel
  RMS 0.08 px, the typical value of Intel's white paper "Tuning depth cameras for best
  performance" (RMS error = z^2 * subpixel / (f * b)), which gives 0.7% at 2 m (D435) and
  0.75% at 4 m (D455), inside the datasheet's "< 2% at 2 m / 4 m".
- Microsoft Kinect v1: baseline 75 mm, IR focal length 580 px, disparity in 1/8 px steps
  (K. Konolige, P. Mihelich, "Technical description of Kinect calibration", ROS wiki, 2011);
  random error "up to about 4 cm at the maximum range" of 5 m (K. Khoshelham, S. O. Elberink,
  "Accuracy and resolution of Kinect depth data for indoor mapping applications", Sensors 12,
  2012), i.e. sigma_d = 0.04 * 580 * 0.075 / 25 = 0.07 px; range 0.5 - 5 m.
The dark, glossy and edge thresholds are this model's choices, not datasheet figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from calib.camera import CameraModel
from sdvl.errors import InputError
from sim.synth.raycast import Surfaces, camera_rays

D4_FOCAL_PX = 424.0 / math.tan(math.radians(87.0 / 2))  # D435/D455 depth at 848x480


@dataclass(frozen=True)
class DepthSensor:
    """A depth camera's error model (see the module docstring); lengths in metres."""

    name: str
    focal_px: float
    baseline_m: float
    disparity_noise_px: float
    disparity_step_px: float  # 0: disparity not quantised
    min_m: float
    max_m: float
    unit_m: float  # the depth image's unit (16-bit values)
    edge_rel: float = 0.05  # a 4-neighbour this much nearer or farther drops the pixel
    dark_level: float = 25.0  # grey level (0..255) below which returns fade out
    glare_deg: float = 20.0  # glossy surfaces: no depth this close to normal incidence
    glossy_dropout: float = 0.5  # glossy surfaces: fraction of the other pixels lost
    shadows: bool = True  # occlusion shadows of the second viewpoint

    def sigma(self, z: np.ndarray | float) -> np.ndarray | float:
        """RMS depth error (m) at depth z (m): z^2 sigma_d / (f b)."""
        return np.square(z) * self.disparity_noise_px / (self.focal_px * self.baseline_m)

    def step(self, z: np.ndarray | float) -> np.ndarray | float:
        """Depth quantisation step (m) at depth z: the disparity step's, at least the unit."""
        return np.maximum(np.square(z) * self.disparity_step_px
                          / (self.focal_px * self.baseline_m), self.unit_m)


SENSORS = {
    "d435": DepthSensor("d435", D4_FOCAL_PX, 0.050, 0.08, 0.0, 0.28, 10.0, 0.001),
    "d455": DepthSensor("d455", D4_FOCAL_PX, 0.095, 0.08, 0.0, 0.52, 10.0, 0.001),
    "kinect-v1": DepthSensor("kinect-v1", 580.0, 0.075, 0.07, 0.125, 0.5, 5.0, 0.001),
    # no noise, no holes: the rendered depth within 0.1-20 m, for tests of what uses depth
    "ideal": DepthSensor("ideal", 580.0, 0.075, 0.0, 0.0, 0.1, 20.0, 0.0, edge_rel=np.inf,
                         dark_level=0.0, glare_deg=0.0, glossy_dropout=0.0, shadows=False),
}


def depth_sensor(name: str) -> DepthSensor:
    """A sensor of SENSORS by name; InputError naming the known ones otherwise."""
    if name not in SENSORS:
        raise InputError(f"unknown depth sensor '{name}' (known: {', '.join(SENSORS)})")
    return SENSORS[name]


def measure_depth(sensor: DepthSensor, surfaces: Surfaces, camera: CameraModel,
                  T_w_c: np.ndarray, glossy: tuple[int, ...],
                  rng: np.random.Generator) -> np.ndarray:
    """The depth map (float32 m along the optical axis, 0 = no measurement) the sensor gives
    for the rendered `surfaces`; quads with a texture in `glossy` are shiny."""
    h, w = surfaces.depth.shape
    glossy_cos = np.full((h, w), np.nan, np.float32)
    shiny = np.isin(surfaces.quads.texture, glossy)[np.maximum(surfaces.hit, 0)]
    shiny &= surfaces.hit >= 0
    if shiny.any():
        g = surfaces.quads.geometry[surfaces.hit[shiny]]
        normal = np.cross(g[:, 3:6], g[:, 6:9])
        rays = camera_rays(camera)[0][shiny] @ T_w_c[:3, :3].T
        glossy_cos[shiny] = np.abs(np.sum(normal * rays, axis=1))
    noise = rng.standard_normal((h, w), dtype=np.float32)
    chance = rng.random((h, w), dtype=np.float32)
    fb_image = camera.fx * sensor.baseline_m if sensor.shadows else 0.0
    params = np.array([sensor.focal_px * sensor.baseline_m, fb_image,
                       sensor.disparity_noise_px, sensor.disparity_step_px, sensor.min_m,
                       sensor.max_m, sensor.unit_m, sensor.edge_rel, sensor.dark_level,
                       math.cos(math.radians(sensor.glare_deg)), sensor.glossy_dropout])
    return _measure(np.ascontiguousarray(surfaces.depth, dtype=np.float32),
                    np.ascontiguousarray(surfaces.image, dtype=np.float32), glossy_cos, noise,
                    chance, params)


@numba.njit(cache=True, nogil=True)
def _shadowed(z, fb_image):
    """Pixels the second viewpoint (at +baseline along x) cannot see: a point at column u
    appears at u - d(u) there, hidden when a pixel to its right lands at or left of it."""
    h, w = z.shape
    out = np.zeros((h, w), np.bool_)
    for r in range(h):
        lowest = np.inf  # min over columns to the right of u' - d(u')
        for c in range(w - 1, -1, -1):
            if not np.isfinite(z[r, c]):
                continue
            x = c - fb_image / z[r, c]
            if x > lowest + 0.5:
                out[r, c] = True
            lowest = min(lowest, x)
    return out


@numba.njit(cache=True, nogil=True)
def _on_edge(z, r, c, edge_rel):
    """True when a 4-neighbour's depth differs by more than edge_rel of this pixel's."""
    h, w = z.shape
    limit = edge_rel * z[r, c]
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        rr, cc = r + dr, c + dc
        if 0 <= rr < h and 0 <= cc < w and not abs(z[rr, cc] - z[r, c]) <= limit:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _measure(z, albedo, glossy_cos, noise, chance, p):
    fb, fb_image, sigma_d, step_d, min_m, max_m, unit, edge_rel, dark, glare_cos, gloss_drop = (
        p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10])
    h, w = z.shape
    shadow = _shadowed(z, fb_image)
    out = np.zeros((h, w), np.float32)
    for r in range(h):
        for c in range(w):
            zt = z[r, c]
            if not (min_m <= zt <= max_m) or shadow[r, c] or _on_edge(z, r, c, edge_rel):
                continue
            lost = max(dark - albedo[r, c], 0.0) / dark if dark > 0.0 else 0.0
            g = glossy_cos[r, c]
            if g == g:  # glossy
                if g > glare_cos:
                    continue
                lost = 1.0 - (1.0 - lost) * (1.0 - gloss_drop)
            if chance[r, c] < lost:
                continue
            d = fb / zt + sigma_d * noise[r, c]
            if step_d > 0.0:
                d = np.floor(d / step_d + 0.5) * step_d
            if d <= 0.0:
                continue
            zm = fb / d
            if unit > 0.0:
                zm = np.floor(zm / unit + 0.5) * unit
            if min_m <= zm <= max_m:
                out[r, c] = zm
    return out
