"""The RealSense frame source against a stand-in for Intel's pyrealsense2 (no camera here): the
streams it asks for, depth in metres in the colour pixels, and one clear line when the library
is not installed."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from calib.camera import CameraModel
from calib.depth_camera import DepthSpec
from daemon.config import CameraConfig
from daemon.realsense import RealSenseSource, is_realsense
from daemon.run_command import open_source
from sdvl.errors import InputError

CAMERA = CameraModel(8, 6, 5.0, 5.0, 4.0, 3.0, "none", [])


def fake_pyrealsense2(log: list) -> types.ModuleType:
    """The calls of pyrealsense2 the source makes, recorded in `log`."""
    rs = types.ModuleType("pyrealsense2")
    rs.stream = types.SimpleNamespace(color="color", depth="depth")
    rs.format = types.SimpleNamespace(bgr8="bgr8", z16="z16")
    colour = np.zeros((6, 8, 3), np.uint8)
    colour[..., 2] = 200  # red: grey 0.299 * 200
    raw = np.full((6, 8), 1500, np.uint16)
    raw[0, 0] = 100  # nearer than the sensor's minimum
    frame = types.SimpleNamespace(get_data=lambda: colour)
    depth = types.SimpleNamespace(get_data=lambda: raw, __bool__=lambda self: True)
    frames = types.SimpleNamespace(get_color_frame=lambda: frame, get_depth_frame=lambda: depth)
    device = types.SimpleNamespace(first_depth_sensor=lambda: types.SimpleNamespace(
        get_depth_scale=lambda: 0.001))

    class Config:
        def enable_stream(self, *args):
            log.append(("stream", *args))

        def enable_device(self, serial):
            log.append(("device", serial))

    class Pipeline:
        def start(self, config):
            return types.SimpleNamespace(get_device=lambda: device)

        def wait_for_frames(self, timeout_ms):
            return frames

        def stop(self):
            log.append(("stop",))

    class Align:
        def __init__(self, to):
            log.append(("align", to))

        def process(self, given):
            return given

    rs.config, rs.pipeline, rs.align = Config, Pipeline, Align
    return rs


@pytest.fixture
def rs_log(monkeypatch):
    log: list = []
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake_pyrealsense2(log))
    return log


def test_colour_as_grey_and_depth_in_metres_aligned_to_it(rs_log):
    spec = DepthSpec(scale=0.001, min_m=0.3, max_m=10.0)
    source = RealSenseSource("realsense:123", CAMERA, spec, 30.0, depth=True)
    source.open()
    t, t_capture, image, depth = source.read()
    source.close()
    assert ("device", "123") in rs_log and ("align", "color") in rs_log
    assert ("stream", "depth", 8, 6, "z16", 30) in rs_log and ("stop",) in rs_log
    assert image.dtype == np.uint8 and image.shape == (6, 8) and 55 <= image[0, 0] <= 65
    assert depth.dtype == np.float32 and depth[1, 1] == pytest.approx(1.5)
    assert depth[0, 0] == 0.0  # outside the valid range: a hole
    assert t == t_capture


def test_without_depth_only_the_colour_stream(rs_log):
    source = RealSenseSource("realsense", CAMERA, None, 30.0, depth=False)
    source.open()
    assert len(source.read()) == 3
    assert [entry[1] for entry in rs_log if entry[0] == "stream"] == ["color"]


def test_missing_library_is_one_clear_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import fails
    assert is_realsense("realsense:0451") and not is_realsense("/dev/video0")
    with pytest.raises(InputError, match="pip install 'sdvl-companion\\[realsense\\]'"):
        RealSenseSource("realsense", CAMERA, None, 30.0, depth=True)
    with pytest.raises(InputError, match=r"camera\.calibration"):
        open_source(CameraConfig(source="realsense"))


def test_depth_asked_of_a_camera_without_depth_is_a_config_error():
    with pytest.raises(InputError, match="gives no depth maps"):
        open_source(CameraConfig(source="testpattern", depth=True))
