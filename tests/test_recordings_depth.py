"""Depth from a recorded folder played as the service's camera (issue 30): `sdvl run` with
camera.source a folder and camera.depth on gets each frame's depth map from the folder's
depth.txt (shared-data layout or TUM RGB-D as distributed), a bad depth file is counted and its
image tracked without it, and camera.depth on a folder without depth stops the start. The
service's recorder (camera.record) writes a flight that plays back with its depth."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from daemon_helpers import BUSY_SLACK, RunningService, service_config
from test_depth_service import DepthTracker

from calib.camera import CameraModel
from calib.camera_yaml import load_depth_spec, save_camera
from calib.depth_camera import DepthSpec
from daemon.camera import RecordingSource, SequenceSource
from daemon.config import CameraConfig
from daemon.frame_recorder import FrameRecorder
from daemon.frames import BadDepth, Frame, UnreadableDepth
from daemon.recordings import open_recording
from daemon.run_command import frame_recorder, open_source
from sdvl.errors import InputError
from sim.autopilot import SimAutopilot, configured_options
from sim.sequence import Sequence

CAMERA = CameraModel(64, 48, 50.0, 50.0, 32.0, 24.0, "none", [])


def depth_folder(folder: Path, n: int, tum: bool = False, depth: bool = True,
                 yaml: bool = True) -> list[np.ndarray]:
    """n frames with a raw 16-bit depth PNG each; TUM: rgb.txt, depth 4 ms after colour on its
    own clock, 5000 units per metre (no depth keys); else frames.txt, 1 mm units stated in
    camera.yaml. Frame 3's depth map is not listed (no depth for it). Returns the raw maps."""
    rng = np.random.default_rng(5)
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    frames, depths, raws = [], [], []
    for k in range(n):
        t = 100.0 + k / 30
        cv2.imwrite(str(folder / f"rgb/{k}.png"), rng.integers(0, 255, (48, 64), np.uint8))
        raw = rng.integers(300, 20000, (48, 64)).astype(np.uint16)
        raw[rng.random((48, 64)) < 0.1] = 0  # holes
        cv2.imwrite(str(folder / f"depth/{k}.png"), raw)
        raws.append(raw)
        frames.append(f"{t:.6f} rgb/{k}.png")
        if k != 3:
            depths.append(f"{t + (0.004 if tum else 0.0):.6f} depth/{k}.png")
    (folder / ("rgb.txt" if tum else "frames.txt")).write_text("\n".join(frames) + "\n")
    if depth:
        (folder / "depth.txt").write_text("# timestamp filename\n" + "\n".join(depths) + "\n")
    if yaml:
        save_camera(CAMERA, folder / "camera.yaml", depth=None if tum else DepthSpec(0.001))
    return raws


def read_all(source: RecordingSource) -> list[tuple]:
    source.open()
    items = []
    while (item := source.read()) is not None:
        items.append(item)
    return items


@pytest.mark.parametrize("tum, unit", [(False, 0.001), (True, 1 / 5000)])
def test_recorded_depth_comes_with_each_frame_as_written(tmp_path, tum, unit):
    raws = depth_folder(tmp_path / "rec", 6, tum=tum)
    items = read_all(RecordingSource(open_recording(tmp_path / "rec"), realtime=False,
                                     depth=True))
    assert len(items) == 6 and all(len(item) == 4 for item in items)
    assert items[3][3] is None  # no depth map listed near frame 3
    for k in (0, 1, 2, 4, 5):
        depth = items[k][3]
        assert depth.dtype == np.float32 and depth.shape == (48, 64)
        np.testing.assert_allclose(depth, raws[k] * unit, rtol=1e-6)
        assert np.array_equal(depth == 0, raws[k] == 0)


def test_a_corrupt_or_missing_depth_file_is_unreadable_depth_and_the_stream_goes_on(tmp_path):
    raws = depth_folder(tmp_path / "rec", 6)
    (tmp_path / "rec/depth/1.png").write_bytes(b"\x89PNG not really" * 20)
    (tmp_path / "rec/depth/4.png").unlink()
    items = read_all(RecordingSource(open_recording(tmp_path / "rec"), realtime=False,
                                     depth=True))
    unreadable = [isinstance(item[3], UnreadableDepth) for item in items]
    assert unreadable == [False, True, False, False, True, False]
    assert items[3][3] is None and all(isinstance(items[k][3], np.ndarray) for k in (0, 2, 5))
    assert "depth/1.png" in items[1][3].detail and "depth/4.png" in items[4][3].detail
    assert isinstance(items[1][2], np.ndarray)  # the image itself is there
    np.testing.assert_allclose(items[5][3], raws[5] * 0.001, rtol=1e-6)


def test_without_camera_depth_a_recording_gives_images_only(tmp_path):
    depth_folder(tmp_path / "rec", 3)
    items = read_all(RecordingSource(open_recording(tmp_path / "rec"), realtime=False))
    assert [len(item) for item in items] == [3, 3, 3]


def test_the_service_tracks_recorded_depth_and_counts_a_bad_depth_file(tmp_path):
    depth_folder(tmp_path / "rec", 12)
    (tmp_path / "rec/depth/7.png").write_bytes(b"")
    tracker = DepthTracker()
    source = open_source(CameraConfig(source=str(tmp_path / "rec"), realtime=False, depth=True))
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, camera={"depth": True}), tracker=tracker,
                             source=source)
        run.thread.join(10.0 * BUSY_SLACK)
    assert run.exit_code == 0 and tracker.index == 12  # every image tracked
    assert [d is not None for d in tracker.depths] == [k not in (3, 7) for k in range(12)]
    assert run.service.capture.check.depth_counts == {BadDepth.UNREADABLE: 1}


def test_camera_calibration_gives_a_folder_without_camera_yaml_its_depth(tmp_path):
    raws = depth_folder(tmp_path / "rec", 3, tum=True, yaml=False)
    save_camera(CAMERA, tmp_path / "calib.yaml")
    source = open_source(CameraConfig(source=str(tmp_path / "rec"), realtime=False,
                                      calibration=str(tmp_path / "calib.yaml"), depth=True))
    np.testing.assert_allclose(read_all(source)[2][3], raws[2] / 5000, rtol=1e-6)


def test_camera_depth_on_a_folder_without_depth_is_a_one_line_start_error(tmp_path):
    depth_folder(tmp_path / "rec", 3, depth=False)
    with pytest.raises(InputError) as err:
        open_source(CameraConfig(source=str(tmp_path / "rec"), depth=True))
    message = str(err.value)
    assert "camera.depth = false" in message and "depth.txt" in message and "\n" not in message



def _flight_with_depth(n: int) -> tuple[Sequence, list]:
    """n frames whose depth maps are random metres with holes (NaN and 0); frame 2 has none,
    frame 4's file is unreadable."""
    rng = np.random.default_rng(8)
    images = [rng.integers(0, 255, (48, 64), np.uint8) for _ in range(n)]
    depths = []
    for k in range(n):
        depth = rng.uniform(0.3, 5.0, (48, 64)).astype(np.float32)
        depth[rng.random((48, 64)) < 0.1] = np.nan
        depth[:2] = 0.0
        depths.append(None if k == 2 else depth)

    def load(k: int):
        if k == 4:
            raise InputError("cannot read depth image (missing or corrupt)")
        return depths[k]

    sequence = Sequence("flight", CAMERA, 50.0 + np.arange(n) / 30, image_loader=images.__getitem__,
                        depth_loader=load)
    return sequence, [images, depths]


def test_recorded_flight_replays_with_its_depth(tmp_path):
    sequence, (images, depths) = _flight_with_depth(10)
    recorder = FrameRecorder(tmp_path / "rec", lambda width, height: CAMERA, depth=True)
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, camera={"depth": True}),
                             source=SequenceSource(sequence, realtime=False, depth=True),
                             recorder=recorder)
        run.thread.join(10.0 * BUSY_SLACK)
    assert run.exit_code == 0 and recorder.written == 10 and recorder.error is None
    (folder,) = (tmp_path / "rec").iterdir()
    assert recorder.folder == folder and load_depth_spec(folder / "camera.yaml").scale == 0.001
    items = read_all(RecordingSource(open_recording(folder), realtime=False, depth=True))
    assert [item[0] for item in items] == pytest.approx(list(sequence.timestamps), abs=1e-6)
    assert all(np.array_equal(item[2], image) for item, image in zip(items, images, strict=True))
    assert items[2][3] is None and items[4][3] is None  # none given, unreadable: none recorded
    for k in (0, 1, 3, 5, 9):
        want = np.nan_to_num(depths[k])
        assert np.abs(items[k][3] - want).max() <= 0.0005 + 1e-6  # 1 mm units
        assert np.array_equal(items[k][3] == 0, want == 0)


def test_a_recorder_that_cannot_write_stops_and_says_why(tmp_path):
    (tmp_path / "full").write_text("a file where the folder should be")
    recorder = FrameRecorder(tmp_path / "full", lambda width, height: CAMERA, depth=False)
    recorder.start()
    frame = Frame(0, 1.0, 1.0, np.zeros((48, 64), np.uint8))
    recorder.offer(frame)
    deadline = time.monotonic() + 5.0
    while recorder.error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    recorder.offer(frame)  # ignored from now on
    recorder.stop(2.0)
    assert recorder.error and recorder.written == 0 and not recorder.is_alive()
    assert frame_recorder(CameraConfig(), CAMERA) is None  # camera.record empty: off
