"""Imaging effects applied to the ideal rendering: exposure changes, vignetting, motion blur
(by averaging sub-frames over the shutter time) and sensor noise."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from calib.camera import CameraModel

DARK_LEVEL = 4.0  # DN of a covered lens


@dataclass(frozen=True)
class Effects:
    """How the camera degrades the image; all off gives the ideal rendering."""

    read_noise: float = 1.2  # DN std
    shot_noise: float = 0.03  # variance per DN of signal
    vignetting: float = 0.25  # fraction of brightness lost in the image corners
    exposure_swing: float = 0.08  # relative brightness change (slow auto-exposure hunting)
    exposure_period: float = 11.0  # s
    shutter: float = 0.004  # s, exposure time (motion blur)
    max_subframes: int = 8  # motion blur samples at most; 1 disables blur


IDEAL = Effects(0.0, 0.0, 0.0, 0.0, 11.0, 0.0, 1)


@functools.lru_cache(maxsize=8)
def vignette(camera: CameraModel, strength: float) -> np.ndarray:
    """(H, W) float32 brightness factor: cos^4 of the ray angle, scaled to lose `strength` at
    the corners."""
    if strength <= 0.0:
        return np.ones((camera.height, camera.width), np.float32)
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    cos = camera.unproject(np.column_stack([u.ravel(), v.ravel()]))[:, 2]
    c4 = cos.reshape(camera.height, camera.width) ** 4
    return (1.0 - strength * (1.0 - c4) / max(1.0 - c4.min(), 1e-9)).astype(np.float32)


def exposure_gain(effects: Effects, t: float, phase: float) -> float:
    """Relative brightness at time t (two incommensurate slow oscillations)."""
    w = 2 * math.pi / effects.exposure_period
    return 1.0 + effects.exposure_swing * (0.7 * math.sin(w * t + phase)
                                           + 0.3 * math.sin(2.7 * w * t + 2 * phase))


def subframe_count(effects: Effects, focal: float, speed: float, rate: float,
                   near_depth: float) -> int:
    """Sub-frames needed so that no pixel moves more than ~1 px between two of them."""
    motion_px = focal * effects.shutter * (rate + speed / max(near_depth, 0.05))
    return int(min(max(math.ceil(motion_px), 1), effects.max_subframes))


def finish(image: np.ndarray, camera: CameraModel, effects: Effects, gain: float,
           rng: np.random.Generator) -> np.ndarray:
    """The uint8 frame a camera gives for ideal radiance `image` (float, 0..255)."""
    out = image * (gain * vignette(camera, effects.vignetting))
    if effects.read_noise > 0 or effects.shot_noise > 0:
        std = np.sqrt(effects.read_noise**2 + effects.shot_noise * np.maximum(out, 0.0))
        out = out + std * rng.standard_normal(out.shape, dtype=np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
