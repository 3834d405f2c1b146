"""Frame sources: newest-only handoff, real-time and as-fast-as-possible playback, video files,
reconnecting to a camera that is not there."""

from __future__ import annotations

import ast
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from daemon_helpers import BUSY_SLACK, FakeTracker, RunningService, service_config, wait_for

from calib.camera import CameraModel
from calib.camera_yaml import save_camera
from daemon.camera import CaptureThread, OpenCVSource, SequenceSource, TestPatternSource
from daemon.frames import Frame, LatestSlot
from sdvl.errors import InputError
from sim.autopilot import SimAutopilot, configured_options
from sim.sequence import Sequence

CAMERA = CameraModel(64, 48, 50.0, 50.0, 32.0, 24.0, "none", [])


def tiny_sequence(n: int = 40, fps: float = 30.0) -> Sequence:
    rng = np.random.default_rng(3)
    images = [rng.integers(0, 255, (48, 64), dtype=np.uint8) for _ in range(n)]
    return Sequence("tiny", CAMERA, 100.0 + np.arange(n) / fps,
                    image_loader=lambda i: images[i])


def test_latest_slot_drops_the_oldest_frame():
    slot = LatestSlot()
    image = np.zeros((2, 2), np.uint8)
    for i in range(3):
        slot.put(Frame(i, i, i, image))
    assert slot.get(0.1).index == 2 and slot.dropped == 2
    assert slot.get(0.01) is None
    slot.close()
    assert not slot.put(Frame(9, 9, 9, image))


def test_latest_slot_waits_in_replay_mode():
    slot = LatestSlot()
    image = np.zeros((2, 2), np.uint8)
    slot.put(Frame(0, 0, 0, image), wait=True)
    taken = []
    threading.Timer(0.1, lambda: taken.append(slot.get(1.0))).start()
    start = time.monotonic()
    slot.put(Frame(1, 1, 1, image), wait=True)  # blocks until frame 0 was taken
    assert time.monotonic() - start > 0.05
    assert taken[0].index == 0 and slot.get(1.0).index == 1 and slot.dropped == 0


def replay(realtime: bool, n: int = 40) -> tuple[RunningService, SimAutopilot, list]:
    tracked = []
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url),
                             source=SequenceSource(tiny_sequence(n), realtime=realtime),
                             on_tracked=lambda tf, sent: tracked.append(tf))
        run.thread.join(10.0 * BUSY_SLACK)  # a finite source ends the service by itself
        assert not run.thread.is_alive()
    return run, sim, tracked


def test_fast_replay_tracks_every_frame_and_ends():
    run, _, tracked = replay(realtime=False)
    assert run.exit_code == 0
    assert [tf.frame_index for tf in tracked] == list(range(40))
    assert [tf.t_source for tf in tracked] == list(100.0 + np.arange(40) / 30.0)
    assert run.service.capture.slot.dropped == 0
    assert run.tracker.closed


def test_realtime_replay_plays_at_the_sequence_timestamps():
    run, sim, tracked = replay(realtime=True)
    # a live source drops the oldest frame when tracking is behind (a busy machine): every
    # frame is tracked or counted as dropped, in order
    dropped = run.service.capture.slot.dropped
    assert run.exit_code == 0 and len(tracked) > 0 and len(tracked) + dropped == 40
    indices = [tf.frame_index for tf in tracked]
    assert indices == sorted(set(indices))
    captures = np.array([tf.t_capture for tf in tracked])
    sources = np.array([tf.t_source for tf in tracked])
    lag = (captures - captures[0]) - (sources - sources[0])
    assert lag.min() > -0.002  # never ahead of the sequence's clock
    stamps = np.array([r.msg.time_usec for r in sim.messages("ODOMETRY")]) / 1e6
    assert 0 < len(stamps) <= len(tracked) and np.all(np.diff(stamps) > 0.5 / 30.0)


def test_video_file_source(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    rng = np.random.default_rng(5)
    for _ in range(10):
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    source = OpenCVSource(str(path), realtime=False)
    assert source.finite and not source.live
    source.open()
    frames = []
    while (item := source.read()) is not None:
        frames.append(item)
    source.close()
    assert len(frames) == 10
    assert frames[0][2].shape == (48, 64) and frames[0][2].dtype == np.uint8
    assert np.allclose(np.diff([f[0] for f in frames]), 1 / 25.0, atol=1e-3)


def test_missing_device_retries_with_backoff():
    slot = LatestSlot()
    states = []
    thread = CaptureThread(OpenCVSource("/dev/video-sdvl-missing"), slot, (0.02, 0.08),
                           on_state=states.append)
    start = time.monotonic()
    thread.start()
    assert wait_for(lambda: len(states) >= 4, 3.0)
    thread.stop()
    thread.join(1.0)
    assert not thread.is_alive() and set(states) == {"no camera"}
    assert time.monotonic() - start > 0.02 + 0.04 + 0.08  # back-off doubles up to its cap


def test_test_pattern_paces_and_moves():
    source = TestPatternSource(64, 48, fps=50.0)
    source.open()
    frames = [source.read() for _ in range(11)]
    stamps = np.array([f[1] for f in frames])
    assert abs((stamps[-1] - stamps[0]) / 10 - 0.02) < 0.004
    assert not np.array_equal(frames[0][2], frames[5][2])
    assert source.camera.width == 64


def test_tracker_gets_source_time_and_the_estimate_capture_time():
    """The tracker sees the sequence's own clock; MAVLink stamps use the capture clock."""
    seen = []

    class Recording(FakeTracker):
        def process(self, image, t, **extra):
            seen.append(t)
            return super().process(image, t)

    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url), tracker=Recording(),
                             source=SequenceSource(tiny_sequence(10), realtime=False))
        run.thread.join(10.0 * BUSY_SLACK)
    assert seen[0] == 100.0
    stamps = [r.msg.time_usec / 1e6 for r in sim.messages("ODOMETRY")]
    assert stamps and all(abs(s - time.monotonic()) < 30 for s in stamps)


def test_dataset_folder_and_other_sources_from_config(data_dir):
    from daemon.config import CameraConfig
    from daemon.run_command import camera_model, fit_camera, open_source

    source = open_source(CameraConfig(source=str(data_dir / "tum_fr1_rpy"), realtime=False))
    assert isinstance(source, SequenceSource) and not source.live and source.finite
    camera = camera_model(CameraConfig(), source)
    assert (camera.width, camera.height) == (640, 480)
    source.open()
    t, _, image = source.read()
    assert image.shape == (480, 640) and image.dtype == np.uint8 and t > 1e9
    assert fit_camera(camera, 320, 240).fx == camera.fx / 2
    with pytest.raises(InputError, match="calibrate at this size"):
        fit_camera(camera, 320, 200)
    assert isinstance(open_source(CameraConfig(source="testpattern")), TestPatternSource)
    device = open_source(CameraConfig(source="/dev/video0"))
    assert isinstance(device, OpenCVSource) and device.live and not device.finite


def test_gstreamer_pipeline_without_gstreamer_says_so():
    from daemon.camera import HAS_GSTREAMER

    if HAS_GSTREAMER:
        pytest.skip("this OpenCV has GStreamer")
    with pytest.raises(OSError, match="no GStreamer"):
        OpenCVSource("videotestsrc ! videoconvert ! appsink").open()


def test_camera_that_fails_mid_stream_is_reopened():
    """A device that stops delivering (unplugged) is closed and reopened; frames resume."""

    class Flaky(TestPatternSource):
        def __init__(self):
            super().__init__(64, 48, fps=100.0)
            self.opens = self.reads = 0

        def open(self):
            self.opens += 1
            super().open()

        def read(self):
            self.reads += 1
            if self.reads % 10 == 0:
                raise OSError("frame grab failed (device unplugged?)")
            return super().read()

    source, slot, states = Flaky(), LatestSlot(), []
    thread = CaptureThread(source, slot, (0.01, 0.02), on_state=states.append)
    thread.start()
    frames = []
    while len(frames) < 25:
        frame = slot.get(1.0)
        assert frame is not None
        frames.append(frame)
    thread.stop()
    thread.join(1.0)
    assert source.opens >= 3 and states.count("no camera") >= 2
    assert [f.index for f in frames] == sorted({f.index for f in frames})


def test_grey_converts_colour_and_16_bit_frames_the_same_way_every_frame():
    from daemon.camera import grey

    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 2] = 200
    assert grey(bgr).shape == (4, 6) and grey(bgr).dtype == np.uint8
    deep = np.full((4, 6), 0x8000, np.uint16)
    assert (grey(deep) == 0x80).all()


def test_daemon_never_imports_sim():
    """Dependencies point one way (daemon -> vo, calib): not even a lazy import of sim."""
    root = Path(__file__).resolve().parents[1] / "daemon"
    offenders = []
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            offenders += [f"{path.name}:{node.lineno} {n}" for n in names
                          if n == "sim" or n.startswith("sim.")]
    assert offenders == []


def _write_images(folder: Path, names: list[str]) -> list[np.ndarray]:
    folder.mkdir()
    images = [np.full((48, 64), 10 * (k + 1), np.uint8) for k in range(len(names))]
    for name, image in zip(names, images, strict=True):
        cv2.imwrite(str(folder / name), image)
    return images


def _played(folder: Path, fps: float = 30.0) -> tuple[list[float], list[np.ndarray]]:
    from daemon.config import CameraConfig
    from daemon.run_command import camera_model, open_source

    source = open_source(CameraConfig(source=str(folder), fps=fps, realtime=False))
    assert camera_model(CameraConfig(), source) == CAMERA
    source.open()
    items = iter(source.read, None)
    return map(list, zip(*[(t, image) for t, _, image in items], strict=True))


def test_image_folder_and_frame_list_as_camera(tmp_path):
    save_camera(CAMERA, tmp_path / "camera.yaml")  # beside the folder
    images = _write_images(tmp_path / "shots", ["img10.png", "img2.png", "img1.png"])
    times, frames = _played(tmp_path / "shots", fps=10.0)
    assert times == pytest.approx([0.0, 0.1, 0.2])
    assert [f[0, 0] for f in frames] == [30, 20, 10]  # natural order: img1, img2, img10
    folder = tmp_path / "listed"
    _write_images(folder, ["a.png", "b.png"])
    (folder / "frames.txt").write_text("# t path\n5.0 b.png\n5.5 a.png\n")
    save_camera(CAMERA, folder / "camera.yaml")
    times, frames = _played(folder)
    assert times == [5.0, 5.5] and [f[0, 0] for f in frames] == [20, 10]
    assert images[0].shape == frames[0].shape
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no images"):
        _played(tmp_path / "empty")
