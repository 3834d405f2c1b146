"""Compiles the numba kernels most tests call into the checkout's cache, before pytest-xdist
starts its workers (tests/conftest.py): otherwise every worker, and every service a test starts,
compiles the same kernels at once on a clean checkout (a cold suite took 880 s of CPU on 2 cores
against 593 s with the cache filled).

`python tests/precompile.py tracker|scene`: one part; conftest runs both parts side by side,
one process per core.
"""

from __future__ import annotations

import sys

import numpy as np


def tracker() -> None:
    """The tracker's kernels: the service's warm-up pan through the default tracker, then
    through one with ORB matching and local bundle adjustment, and a hold's."""
    from calib.camera import CameraModel
    from daemon.run_command import warm_up
    from vo.config import TrackerConfig
    from vo.depth_segments import segment_distances
    from vo.tracker import Tracker

    width, height = 320, 240
    camera = CameraModel(width, height, 300.0, 300.0, width / 2, height / 2)
    for config in (TrackerConfig(), TrackerConfig(matcher="orb", local_ba=True)):
        warm_up(lambda _frame, config=config: Tracker(camera, config), width, height)
    # a hold's (vo.map_matching), which the warm-up's good frames never need
    segment_distances(np.eye(4), np.eye(4)[None], np.zeros(1, np.int64),
                      np.array([[0.0, 0.0, 1.0]]), np.ones(1), np.ones(1), np.zeros((1, 2)))


def scene() -> None:
    """The kernels that do not touch the tracker's: the synthetic camera's (two frames and a
    depth map of a preset flight), the depth camera's and the occupancy map's."""
    from calib.camera import CameraModel
    from calib.depth_camera import decimate, register_depth
    from sim.synth.flight import synthetic_sequence
    from vo.occupancy import OccupancyMap

    sequence = synthetic_sequence("room-handheld", frames=2, size=(64, 48),
                                  textures="procedural")
    for t, _image in sequence.frames():
        depth = sequence.depth_at(t)
    camera = sequence.camera
    register_depth(depth, camera, CameraModel(32, 24, 25.0, 25.0, 16.0, 12.0), np.eye(4))
    decimate(depth, camera, 2)
    occupancy = OccupancyMap()
    occupancy.insert(np.random.default_rng(0).uniform(-2.0, 2.0, (50, 3)), np.zeros(3))
    occupancy.occupied()


PARTS = {"tracker": tracker, "scene": scene}

if __name__ == "__main__":
    PARTS[sys.argv[1]]()
