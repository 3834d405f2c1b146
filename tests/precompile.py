"""Compiles the numba kernels most tests call into the checkout's cache, before pytest-xdist
starts its workers (tests/conftest.py): otherwise every worker, and every service a test starts,
compiles the same kernels at once on a clean checkout (a cold suite took 880 s of CPU on 2 cores
against 593 s with the cache filled).

`python tests/precompile.py tracker|renderer`: one part; conftest runs both parts side by side,
one process per core.
"""

from __future__ import annotations

import sys

import numpy as np


def tracker() -> None:
    """The tracker's kernels: the warm-up pan (vo.warm_up) through the default tracker, then
    through one with ORB matching and local bundle adjustment."""
    from calib.camera import CameraModel
    from vo.config import TrackerConfig
    from vo.tracker import Tracker
    from vo.warm_up import warm_up

    width, height = 320, 240
    camera = CameraModel(width, height, 300.0, 300.0, width / 2, height / 2)
    for config in (TrackerConfig(), TrackerConfig(matcher="orb", local_ba=True)):
        tracker = Tracker(camera, config)
        try:
            warm_up(tracker.process, width, height)
        finally:
            tracker.close()


def renderer() -> None:
    """The synthetic camera's kernels: two frames and a depth map of a preset flight."""
    from sim.synth.flight import synthetic_sequence

    sequence = synthetic_sequence("room-handheld", frames=2, size=(64, 48),
                                  textures="procedural")
    for t, image in sequence.frames():
        assert np.isfinite(image).all()
        sequence.depth_at(t)


PARTS = {"tracker": tracker, "renderer": renderer}

if __name__ == "__main__":
    PARTS[sys.argv[1]]()
