"""The frames a real-time replay renders first, in forked worker processes."""

from __future__ import annotations

import signal

import numpy as np

from calib.camera import CameraModel
from sim.replay.prerender import prerendered
from sim.sequence import Sequence


def _sigterm_is_default(i: int) -> np.ndarray:
    """Frame i: its first pixel is i, the second 1 when the rendering process ends on SIGTERM."""
    image = np.zeros((24, 32), np.uint8)
    image[0, 0] = i
    image[0, 1] = signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    return image


def test_frames_render_in_workers_that_end_on_sigterm(tmp_path):
    """`sdvl run` leaves SIGTERM only setting a flag; the pool's exit ends idle workers with
    SIGTERM, so a worker that kept that handler never ended (a CI run hung on it)."""
    camera = CameraModel(32, 24, 30.0, 30.0, 16.0, 12.0)
    sequence = Sequence("ramp", camera, np.arange(10) / 30.0, image_loader=_sigterm_is_default)
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: None)
    try:
        done: list[int] = []
        rendered, alongside = prerendered(sequence, tmp_path, 10, done.append, lambda: 42)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert alongside == 42
    assert sorted(done) == list(range(1, 11))
    frames = [rendered.image_loader(i) for i in range(10)]
    assert [int(f[0, 0]) for f in frames] == list(range(10))
    assert all(f[0, 1] == 1 for f in frames)
