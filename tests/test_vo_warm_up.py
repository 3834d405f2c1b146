"""The tracker's warm-up pan: it must reach every stage a real run reaches, or kernels the pan
leaves out are compiled (or loaded) in flight."""

from __future__ import annotations

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.tracker import Tracker
from vo.warm_up import BLANK_FRAMES, PAN_FRAMES, RETURN_FRAMES, pan_frames, warm_up


def test_the_pan_maps_keyframes_loses_and_relocalises():
    camera = CameraModel(320, 240, 240.0, 240.0, 159.5, 119.5)
    tracker = Tracker(camera, TrackerConfig(outlier_rejection=True))
    results = []
    assert warm_up(lambda image, t: results.append(tracker.process(image, t)), 320, 240) > 0
    assert len(results) == PAN_FRAMES + BLANK_FRAMES + RETURN_FRAMES
    pan = results[:PAN_FRAMES]
    assert pan[0].quality == "initializing" and any(r.new_segment for r in pan)
    assert sum(r.keyframe for r in pan) >= 2  # the initial map's, and one the mapper extends
    assert tracker.mapper.n_keyframes_added >= 1
    assert all("ransac" in r.timings for r in pan[-5:])
    assert results[PAN_FRAMES + BLANK_FRAMES - 1].quality == "lost"
    found, back = results[-RETURN_FRAMES:-RETURN_FRAMES + 2]
    # relocalised into the map it lost (a jump, so a new segment, in the same map): found in
    # the first frame back, confirmed by the next (vo.relocalizing)
    assert "relocalize" in found.timings and not found.has_pose
    assert back.has_pose and back.new_segment and back.relocalized


def test_frames_are_the_cameras_size_and_repeat():
    first = [image for _, image in pan_frames(64, 48)]
    again = [image for _, image in pan_frames(64, 48)]
    assert all(a.shape == (48, 64) and a.dtype == "uint8" and a.flags.c_contiguous
               for a in first)
    assert all((a == b).all() for a, b in zip(first, again, strict=True))


def test_the_service_warms_a_throwaway_tracker_up_once_before_its_first(monkeypatch):
    """`sdvl run` builds its trackers with warm_first: the first build warms a throwaway one
    at the frame's size (kernels compiled before the first real frame, not in flight); a
    rebuild after a failure does not warm again."""
    import time

    import numpy as np

    from daemon import run_command
    from daemon.config import Config
    from daemon.frames import Frame

    warmed = []
    monkeypatch.setattr(run_command, "warm_up",
                        lambda make, width, height: warmed.append((width, height)) or 0.1)
    camera = CameraModel(320, 240, 240.0, 240.0, 159.5, 119.5)
    make = run_command.tracker_factory(Config(), camera, warm_first=True)
    frame = Frame(0, 0.0, time.monotonic(), np.zeros((240, 320), np.uint8))
    first, second = make(frame), make(frame)
    assert warmed == [(320, 240)] and first is not second
    first.close()
    second.close()
    run_command.tracker_factory(Config(), camera)(frame).close()
    assert len(warmed) == 1  # without warm_first (replays warm up before their clock starts)
