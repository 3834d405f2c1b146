"""Depth through the service (issue 30): each frame's depth map from the source to the tracker,
a bad depth map counted and the image tracked without it, the fusion's metric mode (no scale
state) and a replay with depth publishing metric positions from its first tracked frame."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from daemon_helpers import BUSY_SLACK, FakeTracker, RunningService, service_config
from test_daemon_sources import CAMERA, tiny_sequence

from calib.camera import CameraModel
from daemon.camera import SequenceSource
from daemon.config import Config, replace
from daemon.frames import BadDepth, FrameCheck, UnreadableDepth
from daemon.fusion.config import FusionConfig
from daemon.fusion.scene import SceneTracker
from daemon.fusion.state import LOG_SCALE, NavFilter, ScaleSource
from sdvl.errors import InputError
from sim.autopilot import SimAutopilot, configured_options
from sim.replay.harness import run_replay
from sim.replay.report import build_report
from sim.sequence import Sequence
from sim.synth.flight import synthetic_sequence

GOOD = np.full((48, 64), 2.0, np.float32)
# frame index -> what the depth camera gave for it; every other frame has GOOD
BAD = {5: np.zeros((24, 32), np.float32), 6: (GOOD * 1000).astype(np.uint16),
       7: np.zeros((48, 64), np.float32), 8: np.full((48, 64), np.nan, np.float32)}


def _depth(index: int) -> np.ndarray:
    if index == 9:
        raise InputError("cannot read depth image (missing or corrupt)")
    return BAD.get(index, GOOD)


class DepthTracker(FakeTracker):
    """FakeTracker that keeps what depth came with each frame."""

    def __init__(self):
        super().__init__()
        self.depths: list[np.ndarray | None] = []

    def process(self, image, t, depth=None, **extra):
        self.depths.append(depth)
        return super().process(image, t)


def test_check_counts_each_bad_depth_kind_and_logs_it_once(caplog):
    check = FrameCheck()
    image = np.zeros((48, 64), np.uint8)
    with caplog.at_level(logging.WARNING, "sdvl.camera"):
        for _ in range(2):
            for index in (5, 6, 7, 8):
                assert check.depth(BAD[index], image) is None
            assert check.depth(UnreadableDepth("gone"), image) is None
        assert check.depth(GOOD, image) is GOOD
        assert check.depth(None, image) is None
    assert check.depth_counts == {BadDepth.WRONG_SIZE: 2, BadDepth.WRONG_TYPE: 2,
                                  BadDepth.ALL_HOLES: 4, BadDepth.UNREADABLE: 2}
    lines = [r.getMessage() for r in caplog.records if "without its depth" in r.getMessage()]
    assert len(lines) == 4 and any("register depth" in line for line in lines)


def test_bad_depth_frames_are_tracked_without_depth_through_the_service():
    sequence = tiny_sequence(20)
    sequence.depth_loader = _depth
    tracker = DepthTracker()
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url), tracker=tracker,
                             source=SequenceSource(sequence, realtime=False, depth=True))
        run.thread.join(10.0 * BUSY_SLACK)
    assert run.exit_code == 0 and tracker.index == 20  # every image tracked, none failed
    assert not run.service.tracking.failures
    given = [d is not None for d in tracker.depths]
    assert given == [i not in (5, 6, 7, 8, 9) for i in range(20)]
    assert all(d is GOOD for d in tracker.depths if d is not None)
    assert sum(run.service.capture.check.depth_counts.values()) == 5


def test_depth_asked_of_a_sequence_without_depth_is_a_config_error():
    with pytest.raises(InputError, match=r"camera\.depth"):
        SequenceSource(Sequence("plain", CAMERA, np.arange(3.0)), depth=True)


class _MapTracker:
    """The few attributes of vo.Tracker that SceneTracker reads."""

    def __init__(self):
        self.map, self.depth_mode, self.last = object(), False, None
        self.results: list = []

    def process(self, image, t, depth=None, **extra):
        return self.results.pop(0)


def test_a_map_is_metric_when_it_started_from_depth_and_stays_what_it_was():
    from vo.result import FrameResult, Quality

    inner = _MapTracker()
    scene = SceneTracker(inner)
    pose = np.eye(4)

    def step(new_segment: bool) -> bool:
        inner.results.append(FrameResult(0.0, pose, Quality.GOOD, new_segment=new_segment))
        return scene.process(np.zeros((4, 4), np.uint8), 0.0).metric

    assert not step(True)  # a monocular map
    inner.depth_mode = True  # depth came later: that map is still monocular, relocalised too
    assert not step(False) and not step(True)
    inner.map = object()  # a new map, started from depth
    assert step(True) and step(False) and step(True)


def test_metric_map_has_no_scale_state():
    cfg = FusionConfig()
    f = NavFilter(cfg)
    f.start(0.0, cfg.rest_velocity_std)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), np.log(3.0), 0.5, metric=True)
    assert f.scale_source is ScaleSource.METRIC and f.scale == 1.0
    f.x[3:6] = (2.0, 1.0, -1.0)  # flying: a monocular map's scale would walk
    for k in range(1, 50):
        f.predict(0.02 * k, np.array([0.0, 0.0, -9.8]), np.eye(3))
    assert f.x[LOG_SCALE] == 0.0
    assert not np.any(f.P[LOG_SCALE]) and not np.any(f.P[:, LOG_SCALE])
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.3)  # a monocular map: a scale again
    assert f.scale_source is ScaleSource.PRIOR and f.P[LOG_SCALE, LOG_SCALE] > 0


@pytest.fixture(scope="module")
def depth_replay(tmp_path_factory):
    sequence = synthetic_sequence("hover-down", frames=30)
    config = replace(Config(), camera={"depth": True})
    run = run_replay(sequence, config, realtime=False, progress=False)
    report = build_report(run, tmp_path_factory.mktemp("replay"))[0]
    return sequence, run, report


def test_replay_with_depth_publishes_metric_positions_from_the_first_frame(depth_replay):
    sequence, run, report = depth_replay
    assert run.rows[0]["has_pose"] and run.rows[0]["new_segment"]
    first = run.received[0].fields["time_usec"] / 1e6 - 1000.0  # lockstep's clock offset
    assert first == pytest.approx(sequence.timestamps[0], abs=1e-6)
    assert len(run.received) == len(sequence)
    # metric: the climb we sent is the true one (a monocular map's would be arbitrary units)
    z = np.array([m.fields["z"] for m in run.received])
    truth = run.flight.positions[:, 2]
    climb_truth = np.interp(sequence.timestamps[-1], run.flight.t, truth) - np.interp(
        sequence.timestamps[0], run.flight.t, truth)
    assert climb_truth < -0.2
    assert z[-1] - z[0] == pytest.approx(climb_truth, rel=0.1)
    assert report["nees_position"] < 3.0


def test_obstacle_distances_from_the_depth_frames_at_their_rate():
    camera = CameraModel(160, 120, 100.0, 100.0, 79.5, 59.5, "none", [])
    rng = np.random.default_rng(4)
    images = [rng.integers(0, 255, (120, 160), dtype=np.uint8) for _ in range(30)]
    wall = np.full((120, 160), 2.0, np.float32)  # 2 m ahead of the forward camera
    sequence = Sequence("wall", camera, 10.0 + np.arange(30) / 30.0,
                        image_loader=lambda i: images[i], depth_loader=lambda i: wall)
    tracker = DepthTracker()
    tracker.camera = camera
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        config = service_config(sim.url, camera={"depth": True},
                                obstacles={"enabled": True, "rate_hz": 10.0})
        run = RunningService(config, tracker=tracker,
                             source=SequenceSource(sequence, realtime=False, depth=True))
        run.thread.join(10.0 * BUSY_SLACK)
        scans = sim.messages("OBSTACLE_DISTANCE")
    assert run.exit_code == 0
    assert len(scans) == 10  # 10 Hz of a 30 fps second: every third frame
    distances = np.array(scans[0].msg.distances)
    assert distances[0] == pytest.approx(200, abs=2)  # straight ahead
    assert distances[36] == 65535  # behind: unknown
    assert scans[0].msg.frame == 12 and scans[0].msg.increment == 5  # MAV_FRAME_BODY_FRD


def test_obstacles_need_the_depth_camera():
    with pytest.raises(InputError, match="needs camera"):
        replace(Config(), obstacles={"enabled": True})
