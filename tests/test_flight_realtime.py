"""`sdvl fly --realtime`: the real service against the simulated ArduCopter in its own process
on the wall clock. Asserts only what does not depend on the machine's speed: the mission's
steps are run by the autopilot's process, the service's camera gets frames rendered at the
vehicle's pose, and every process started is gone afterwards."""

from __future__ import annotations

import multiprocessing
import struct

import numpy as np
import pytest

from daemon.config import Config
from sim.flight.camera_process import SLOTS, FrameRing, SharedCamera
from sim.flight.mission import parse_mission
from sim.flight.realtime import TruthShare, fly_realtime
from sim.flight.runner import Outcome


def test_truth_crosses_processes_whole():
    share = TruthShare()
    T = np.arange(16.0).reshape(4, 4)
    share.write(2.5, T)
    t, read = TruthShare(share.array).read()
    assert t == 2.5 and np.array_equal(read, T)


def test_realtime_flight_runs_the_mission_beside_a_busy_process():
    mission = parse_mission({"world": "hover-down",
                             "steps": [{"wait": "autopilot"}, {"hold": 2.0}]})
    run = fly_realtime(mission, Config(), 0, (96, 72), (), load=1)
    assert run.realtime and run.load == 1
    assert [r.outcome for r in run.steps] == [Outcome.DONE, Outcome.DONE]
    assert run.rows and run.offered >= len(run.rows)  # the service tracked rendered frames
    assert all(0.0 <= r["t_source"] <= run.truth.t[-1] + 1.0 for r in run.rows)
    assert np.allclose(run.truth.positions[-1][:2], 0.0, atol=1e-6)  # still on its gear
    assert run.record.statustexts  # the autopilot's own record came back from its process
    assert multiprocessing.active_children() == []


def test_frame_ring_hands_over_frames_and_says_when_one_was_overwritten():
    ring = FrameRing((4, 6), depth=True)
    try:
        image, depth = np.full((4, 6), 7, np.uint8), np.full((4, 6), 2.5, np.float32)
        ring.write(3, 0.1, 100.1, image, depth)
        t, t_capture, read_image, read_depth = ring.read(3)
        assert (t, t_capture) == (0.1, 100.1)
        assert np.array_equal(read_image, image) and np.array_equal(read_depth, depth)
        ring.write(3 + SLOTS, 0.2, 100.2, image)  # a reader a whole ring behind
        assert ring.read(3) is None
        assert np.array_equal(ring.read(3 + SLOTS)[3], np.zeros((4, 6), np.float32))
    finally:
        ring.close()


def test_shared_camera_skips_overwritten_frames_and_reports_a_silent_camera():
    ring = FrameRing((2, 2))
    ours, theirs = multiprocessing.Pipe()
    camera = SharedCamera(ours, ring, None)
    try:
        for index in (1, 2, 2 + SLOTS):
            ring.write(index, index / 30, 50 + index / 30, np.full((2, 2), index, np.uint8))
            theirs.send_bytes(struct.pack("<q", index))
        t, _, image = camera.read()  # frame 1; frame 2's slot holds frame 2 + SLOTS now
        assert t == 1 / 30 and image[0, 0] == 1
        t, _, image = camera.read()
        assert image[0, 0] == 2 + SLOTS and camera.overwritten == 1
        assert camera.offered == 2 + SLOTS
        theirs.close()
        with pytest.raises(OSError, match="ended"):
            camera.read()
    finally:
        ring.close()
