"""Warming the tracker up before it is needed: a throwaway tracker runs over a short synthetic
pan across a textured plane, so that numba compiles (first run) or loads from its cache every
kernel the real tracker will call, with the argument types it will call them with. The pan
starts a map, tracks until the view has moved on enough for a new keyframe (mapping kernels),
then the view goes blank until tracking is lost and comes back (relocalisation).

The frames cost nothing to make (shifted crops of one blurred noise image): a warm-up that
renders or reads a sequence's own frames spends more time on them than on the tracker."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import cv2
import numpy as np

PAN_FRAMES = 40
BLANK_FRAMES = 4  # more than lost_after_bad (3) bad frames: tracking is lost
RETURN_FRAMES = 3
PAN_PX = 6  # image shift per frame: a camera moving parallel to a plane
TEXTURE_SIGMA_PX = 1.5  # blur of the noise: corners a few pixels across, as in real images
FPS = 30.0


def pan_frames(width: int, height: int, seed: int = 0) -> Iterator[tuple[float, np.ndarray]]:
    """(t, grey uint8 image) of the warm-up: a pan across a textured plane, blank frames, and
    the view back where the pan ended."""
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (height, width + PAN_FRAMES * PAN_PX)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), TEXTURE_SIGMA_PX)
    texture = cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    blank = np.full((height, width), 128, dtype=np.uint8)
    shifts = list(range(PAN_FRAMES)) + [None] * BLANK_FRAMES + [PAN_FRAMES - 1] * RETURN_FRAMES
    for i, k in enumerate(shifts):
        image = blank if k is None else texture[:, k * PAN_PX:k * PAN_PX + width]
        yield i / FPS, np.ascontiguousarray(image)


def warm_up(process: Callable[[np.ndarray, float], object], width: int, height: int) -> float:
    """Feed the warm-up frames of a width x height camera to `process(image, t)` (a throwaway
    tracker's); returns the seconds it took."""
    start = time.perf_counter()
    for t, image in pan_frames(width, height):
        process(image, t)
    return time.perf_counter() - start
