"""Faults around the tracker never stop the service or make it lie: bad frames are skipped and
counted, a blocked camera or a dead thread ends it with one line for systemd to restart it, a
starved CPU is reported as such, a pose with NaN is never sent."""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from daemon_helpers import BUSY_SLACK, FakeTracker, RunningService, service_config, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from calib.camera import CameraModel
from calib.camera_yaml import save_camera
from daemon.camera import RecordingSource, TestPatternSource
from daemon.estimate import PassThroughEstimator
from daemon.frames import BadFrame, FrameCheck
from daemon.health import Health
from daemon.recordings import open_recording
from sdvl.errors import InputError
from sim.autopilot import SimAutopilot, SimOptions, configured_options

TERMINATION = mavlink2.MAV_STATE_FLIGHT_TERMINATION
CAMERA = CameraModel(64, 48, 50.0, 50.0, 32.0, 24.0, "none", [])


def texts(sim: SimAutopilot) -> list[str]:
    return [r.msg.text for r in sim.messages("STATUSTEXT")]


def recorded_folder(folder: Path, n: int, fps: float, faults: dict[int, str]) -> Path:
    """n frames in a frames.txt; frame k is broken as faults[k] says."""
    folder.mkdir()
    rng = np.random.default_rng(4)
    lines = []
    for k in range(n):
        name = f"{k:04d}.png"
        lines.append(f"{k / fps:.4f} {name}")
        fault = faults.get(k)
        if fault == "missing":
            continue
        image = rng.integers(0, 255, (24, 32) if fault == "wrong size" else (48, 64), np.uint8)
        cv2.imwrite(str(folder / name), image)
        if fault == "truncated":
            data = (folder / name).read_bytes()
            (folder / name).write_bytes(data[: len(data) // 3])
        elif fault == "corrupt":
            (folder / name).write_bytes(b"\x89PNG not really" * 20)
    (folder / "frames.txt").write_text("\n".join(lines) + "\n")
    save_camera(CAMERA, folder / "camera.yaml")
    return folder


def test_bad_recorded_frames_are_skipped_counted_and_reported_once(tmp_path, caplog):
    faults = {5: "missing", 9: "truncated", 12: "corrupt", 15: "wrong size", 18: "missing",
              21: "truncated", 24: "wrong size"}
    folder = recorded_folder(tmp_path / "rec", 40, 30.0, faults)
    source = RecordingSource(open_recording(folder), realtime=True)
    caplog.set_level(logging.WARNING)
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, mavlink={"statustext_interval_s": 0.05}),
                             source=source)
        run.thread.join(10.0 * BUSY_SLACK)
        time.sleep(0.3)
    assert run.exit_code == 0  # the end of the recording, not a failure
    counts = run.service.capture.check.counts
    assert counts == {BadFrame.MISSING: 2, BadFrame.UNREADABLE: 3, BadFrame.WRONG_SIZE: 2}
    assert run.service.stats.frames + run.service.capture.slot.dropped == 40 - len(faults)
    skipped = [r for r in caplog.records if "skipping a frame" in r.getMessage()]
    assert len(skipped) == 3  # once per kind
    assert {"VIO: skipping missing frames", "VIO: skipping unreadable frames",
            "VIO: skipping wrong size frames"} <= set(texts(sim))
    assert len(sim.messages("ODOMETRY")) >= 20


def test_frame_check_kinds_and_a_calibration_that_does_not_fit():
    def fits_64x48(width: int, height: int) -> None:
        if (width, height) != (64, 48):
            raise InputError(f"frames are {width}x{height} but the calibration is 64x48")

    check = FrameCheck(fits_64x48)
    good = np.zeros((48, 64), np.uint8)
    assert not check.check(0.0, np.zeros((24, 32), np.uint8))  # one odd frame first: skipped
    assert check.check(0.1, good) and check.size == (64, 48)
    assert not check.check(0.1, good)  # same stamp again
    assert not check.check(float("nan"), good)
    assert not check.check(0.3, np.zeros((48, 64, 3), np.uint8))
    assert not check.check(0.4, None)
    assert check.check(0.5, good)
    assert check.counts == {BadFrame.WRONG_SIZE: 1, BadFrame.BAD_STAMP: 2, BadFrame.EMPTY: 2}
    starting = FrameCheck(fits_64x48)  # a camera's first second at its default size: skipped
    assert not any(starting.check(k / 30, np.zeros((24, 32), np.uint8)) for k in range(45))
    assert starting.check(1.5, good)
    never = FrameCheck(fits_64x48)
    with pytest.raises(InputError, match="calibration is 64x48"):
        for k in range(100):  # every frame of another size: the configuration is wrong
            never.check(k / 30, np.zeros((24, 32), np.uint8))


def test_folder_renamed_mid_flight_says_frames_unusable_then_recovers(tmp_path):
    folder = recorded_folder(tmp_path / "rec", 200, 50.0, {})
    source = RecordingSource(open_recording(folder), realtime=True)
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, mavlink={"statustext_interval_s": 0.05}),
                             source=source)
        assert wait_for(lambda: run.service.state is Health.GOOD, 3.0)
        folder.rename(tmp_path / "moved")
        assert wait_for(lambda: run.service.state is Health.BAD_FRAMES, 3.0)
        (tmp_path / "moved").rename(folder)
        assert wait_for(lambda: run.service.state is Health.GOOD, 3.0)
        run.thread.join(6.0 * BUSY_SLACK)
        time.sleep(0.2)
    assert run.exit_code == 0
    assert run.service.capture.check.counts[BadFrame.MISSING] >= 40
    said = texts(sim)
    assert "VIO: camera frames unusable" in said and "VIO: camera lost" not in said
    assert Health.BAD_FRAMES.report.system_status == TERMINATION  # in HEARTBEATs meanwhile


class BlockedOpen:
    """A device whose open never returns (a camera that does not answer)."""

    name, camera, live, finite, blocks = "/dev/video-blocked", None, True, False, True

    def __init__(self) -> None:
        self.release = threading.Event()

    def open(self) -> None:
        self.release.wait()

    def read(self) -> None:
        return None

    def close(self) -> None:
        """Nothing to release."""


def test_slow_renderer_is_not_a_blocked_camera():
    """A sequence source (a synthetic flight renders each frame in `read`, compiling its
    kernels on the first) may be slow: only devices are watched for stalls."""

    class SlowFirstFrame(TestPatternSource):
        def read(self):
            if self._index == 0:
                time.sleep(1.0)
            return super().read()

    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url, camera={"stall_timeout_s": 0.3})
        run = RunningService(cfg, source=SlowFirstFrame(64, 48, 30.0))
        assert wait_for(lambda: run.service.stats.frames >= 10, 5.0)
        run.stop()
    assert run.exit_code == 0 and run.service.fault is None


def test_blocked_camera_stops_the_watchdog_and_exits_1_saying_why(caplog):
    source = BlockedOpen()
    notified: list[str] = []

    class Notifier:
        watchdog_interval_s = 0.1

        def notify(self, *lines: str) -> bool:
            notified.extend(lines)
            return True

        def stopping(self) -> None:
            notified.append("STOPPING=1")

    caplog.set_level(logging.ERROR)
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url, camera={"stall_timeout_s": 0.6})
        run = RunningService(cfg, source=source, notifier=Notifier())
        run.thread.join(5.0 * BUSY_SLACK)
        time.sleep(0.2)
    source.release.set()
    assert run.exit_code == 1
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "open has not returned" in errors[0]
    assert "systemd" in errors[0]
    assert "VIO: camera not answering" in texts(sim)
    assert sim.messages("HEARTBEAT")[-1].msg.system_status == TERMINATION
    assert "WATCHDOG=1" not in notified and "READY=1" not in notified
    assert notified[-1] == "STOPPING=1"


class SlowTracker(FakeTracker):
    """Takes longer per frame than a pose may be late: a CPU too busy to keep up."""

    def __init__(self, seconds: float):
        super().__init__()
        self.seconds = seconds

    def process(self, image, t, **extra):
        time.sleep(self.seconds)
        return super().process(image, t)


@pytest.mark.parametrize("seconds", [0.3, 1.5])
def test_starved_cpu_is_reported_as_such_not_as_a_lost_camera(seconds):
    """Frames keep coming from the camera but are tracked too late (0.3 s each) or hardly at
    all (1.5 s each): 'CPU overloaded', never 'camera lost', and nothing stale is sent."""
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url, mavlink={"statustext_interval_s": 0.05})
        run = RunningService(cfg, tracker=SlowTracker(seconds))
        assert wait_for(lambda: run.service.state is Health.CPU_STARVED, 5.0)
        time.sleep(0.3)
        run.stop()
    said = texts(sim)
    assert "VIO: CPU overloaded, poses late" in said and "VIO: camera lost" not in said
    assert sim.messages("ODOMETRY") == []
    assert Health.CPU_STARVED.report.system_status == TERMINATION


class FailingTracker(FakeTracker):
    """Raises on the frames `fails(index)` says."""

    def __init__(self, fails):
        super().__init__()
        self.fails = fails

    def process(self, image, t, **extra):
        if self.fails(self.index):
            self.index += 1
            raise ValueError("a bug on this frame")
        return super().process(image, t)


def test_tracker_failures_on_some_frames_rebuild_it_and_go_on(caplog):
    built: list[FailingTracker] = []
    tracker = FailingTracker(lambda i: i % 15 == 7)

    def make(frame):
        built.append(tracker)
        return tracker

    caplog.set_level(logging.ERROR)
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url), make_tracker=make)
        assert wait_for(lambda: run.service.tracking is not None
                        and run.service.tracking.failures["tracker: ValueError"] >= 3, 5.0)
        run.stop()
    assert run.exit_code == 0 and len(built) >= 3  # built, then rebuilt after each failure
    assert sum("failed on a frame" in r.getMessage() for r in caplog.records) == 1
    assert len(sim.messages("ODOMETRY")) > 20


def test_a_tracker_that_always_fails_ends_the_service_with_code_1(caplog):
    caplog.set_level(logging.ERROR)
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, camera={"fps": 60.0}),
                             tracker=FailingTracker(lambda i: True))
        run.thread.join(5.0 * BUSY_SLACK)
    assert run.exit_code == 1
    last = [r.getMessage() for r in caplog.records][-1]
    assert "tracking thread died" in last and "30 frames in a row" in last


class NanEstimator(PassThroughEstimator):
    """Every other estimate has a NaN position."""

    def on_frame(self, result, t_capture):
        e = super().on_frame(result, t_capture)
        if e is not None and result.t * 30 % 2 < 1:
            e = dataclasses.replace(e, position=e.position * np.array([1.0, np.nan, 1.0]))
        return e


def test_an_estimate_with_nan_is_never_sent():
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url)
        source = TestPatternSource(64, 48, 30.0)
        run = RunningService(cfg, source=source,
                             estimator=NanEstimator(cfg.mounting, cfg.mavlink))
        assert wait_for(lambda: run.service.stats.skipped_not_finite >= 5, 5.0)
        run.stop()
    odometry = [r.msg for r in sim.messages("ODOMETRY")]
    assert odometry and all(np.isfinite([m.x, m.y, m.z]).all() for m in odometry)


class SeenEstimator(PassThroughEstimator):
    """Remembers the sender of every autopilot message it is given."""

    def __init__(self, *args):
        super().__init__(*args)
        self.senders: set[tuple[int, int]] = set()

    def on_autopilot_message(self, msg):
        self.senders.add((msg.get_srcSystem(), msg.get_srcComponent()))
        super().on_autopilot_message(msg)


def test_a_second_system_on_the_link_is_ignored_by_the_running_service():
    """Attitude from system 2 (roll 0.5 rad) injected on the autopilot's link: the service
    stays bound to system 1 and its estimator is never given system 2's messages."""
    intruder = mavlink2.MAVLink(None, srcSystem=2, srcComponent=1)
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url)
        estimator = SeenEstimator(cfg.mounting, cfg.mavlink)
        run = RunningService(cfg, estimator=estimator)
        assert wait_for(lambda: run.service.watch.bound, 5.0)
        for k in range(40):
            msg = intruder.attitude_encode(1000 + 20 * k, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0)
            sim.inject(bytes(msg.pack(intruder)))
            time.sleep(0.01)
        time.sleep(0.2)
        run.stop()
    watch = run.service.watch
    assert (watch.system_id, watch.component_id) == (1, 1)
    assert watch.ignored_sources[(2, 1)] == 40
    assert estimator.senders == {(1, 1)}


class BrokenIntakeEstimator(PassThroughEstimator):
    """Raises on every ATTITUDE it is given (a bug in a message handler)."""

    def on_autopilot_message(self, msg):
        if msg.get_type() == "ATTITUDE":
            raise ValueError("a bug in the handler")
        super().on_autopilot_message(msg)


@pytest.mark.parametrize("port", ["udp", "tcp"])
def test_an_error_handling_a_message_is_counted_and_the_link_stays(port, caplog):
    caplog.set_level(logging.WARNING)
    with SimAutopilot(configured_options(heartbeat_hz=5, port=port)) as sim:
        cfg = service_config(sim.url)
        run = RunningService(cfg, estimator=BrokenIntakeEstimator(cfg.mounting, cfg.mavlink))
        assert wait_for(lambda: run.service.stats.message_errors["ATTITUDE: ValueError"] >= 20,
                        8.0)
        t0 = time.monotonic()
        time.sleep(1.0)
        run.stop()
    assert len(sim.messages("ODOMETRY", since=t0)) >= 15  # still sending over the same link
    assert not any("reopening" in r.getMessage() for r in caplog.records)  # link not lost
    assert sum("handling ATTITUDE failed" in r.getMessage() for r in caplog.records) == 1
