"""What every dataset reader returns: a camera, lazily loaded frames, ground truth and IMU."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.camera import CameraModel
from daemon.recordings import DepthMaps, load_grey
from sdvl.errors import InputError
from sim.trajectory import Trajectory


@dataclass
class ImuSamples:
    """IMU measurements in the sensor frame: accel (N, 3) m/s^2, gyro (N, 3) rad/s or None."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray | None = None


@dataclass
class Sequence(DepthMaps):
    """An image sequence: frames come from `frames()` one at a time, never all in memory.

    `timestamps` are seconds; `image_loader(i)` returns frame i as a grey uint8 image, or
    `frame_iter` yields (t, image) for sources that can only be read in order (video).
    `depth_loader(i)`, where the sequence has depth, returns frame i's depth map (float32
    metres along the optical axis in the frame's pixels, 0 or NaN = no measurement), or None
    when that frame has none.
    """

    name: str
    camera: CameraModel
    timestamps: np.ndarray
    image_loader: Callable[[int], np.ndarray] | None = None
    frame_iter: Callable[[], Iterator[tuple[float, np.ndarray]]] | None = None
    groundtruth: Trajectory | None = None
    imu: ImuSamples | None = None
    extras: dict = field(default_factory=dict)
    depth_loader: Callable[[int], np.ndarray | None] | None = None

    def __len__(self) -> int:
        return int(self.timestamps.size)

    def frames(self, max_frames: int | None = None) -> Iterator[tuple[float, np.ndarray]]:
        """Yield (t_seconds, grey uint8 image) in time order, loading each when asked for."""
        n = len(self) if max_frames is None else min(len(self), max_frames)
        if self.image_loader is not None:
            for i in range(n):
                yield float(self.timestamps[i]), self.image_loader(i)
            return
        assert self.frame_iter is not None
        for i, item in enumerate(self.frame_iter()):
            if i >= n:
                return
            yield item

    def image(self, index: int) -> np.ndarray:
        """Frame `index` (random access; only for image-file sequences)."""
        if self.image_loader is None:
            raise InputError(f"sequence '{self.name}' can only be read in order")
        return self.image_loader(index)

    def depth_at(self, t: float) -> np.ndarray | None:
        """Depth map of the frame at time `t` (None without one)."""
        index = int(np.searchsorted(self.timestamps, t))
        if index >= len(self) or self.timestamps[index] != t:
            raise InputError(f"sequence '{self.name}' has no frame at t = {t}")
        return self.depth(index)


def every(sequence: Sequence, k: int) -> Sequence:
    """Every k-th frame of `sequence` from its first, with the same camera, ground truth and
    IMU: k times the motion between frames (a slower camera, or a faster vehicle)."""
    if k < 1:
        raise InputError("--every must be at least 1")
    if k == 1:
        return sequence
    images, stream, depth = sequence.image_loader, sequence.frame_iter, sequence.depth_loader
    return dataclasses.replace(
        sequence, timestamps=sequence.timestamps[::k],
        image_loader=None if images is None else lambda i: images(i * k),
        frame_iter=None if stream is None else lambda: itertools.islice(stream(), 0, None, k),
        depth_loader=None if depth is None else lambda i: depth(i * k))


def image_list_sequence(name: str, camera: CameraModel, times: np.ndarray, paths: list[Path],
                        **kwargs) -> Sequence:
    """A sequence of image files, one per timestamp, read when each frame is asked for."""
    return Sequence(name, camera, np.asarray(times, dtype=np.float64),
                    image_loader=lambda i: load_grey(paths[i]), **kwargs)
