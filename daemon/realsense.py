"""A live Intel RealSense depth camera (D435, D455, ...) as a frame source, through Intel's
pyrealsense2 (an optional extra: `pip install 'sdvl-companion[realsense]'`).

`camera.source = "realsense"` (the first camera found) or `"realsense:SERIAL"`. The colour stream
becomes the grey image; the depth stream becomes float32 metres in the colour camera's pixels:
librealsense aligns it (rs.align to colour) when camera.yaml says `depth.registered: true`, the
default, else calib.depth_camera registers it with the camera.yaml's depth intrinsics and
T_color_depth. The depth unit is the device's own (get_depth_scale) unless camera.yaml sets
`depth.scale`; `depth.min_m`/`max_m` drop measurements outside the sensor's valid range.
Stream setup and alignment as in librealsense's wrappers/python/examples/align-depth2color.py.
"""

from __future__ import annotations

import importlib
import time

import numpy as np

from calib.camera import CameraModel
from calib.depth_camera import DepthSpec
from daemon.camera import grey
from daemon.frames import UnreadableDepth
from sdvl.errors import InputError

PREFIX = "realsense"
FRAME_TIMEOUT_MS = 2000  # a read waiting longer is a camera gone (the capture thread reopens)


def is_realsense(source: str) -> bool:
    """Whether camera.source names a RealSense camera."""
    return source == PREFIX or source.startswith(PREFIX + ":")


def import_pyrealsense2() -> object:
    """The pyrealsense2 module; InputError in one line when it is not installed."""
    try:
        return importlib.import_module("pyrealsense2")
    except ImportError:
        raise InputError("camera.source 'realsense' needs Intel's pyrealsense2: pip install "
                         "'sdvl-companion[realsense]' (wheels for x86_64 Linux; on ARM boards "
                         "build librealsense with its Python bindings)") from None


class RealSenseSource:
    """A live FrameSource: (t, t_capture, grey image, depth map) per frame set."""

    live, finite, blocks = True, False, True

    def __init__(self, source: str, camera: CameraModel, spec: DepthSpec | None,
                 fps: float, depth: bool):
        self.rs = import_pyrealsense2()
        self.name, self.camera = source, camera
        self.serial = source.partition(":")[2]
        self.spec, self.fps, self.depth = spec, fps, depth
        self._pipeline = None
        self._align = None
        self._scale: DepthSpec | None = None  # the spec with the device's unit when not set

    def open(self) -> None:
        rs = self.rs
        config = rs.config()
        if self.serial:
            config.enable_device(self.serial)
        w, h, fps = self.camera.width, self.camera.height, round(self.fps)
        config.enable_stream(rs.stream.color, w, h, rs.format.bgr8, fps)
        if self.depth:
            spec = self.spec or DepthSpec()
            size = (spec.camera.width, spec.camera.height) if spec.camera else (w, h)
            config.enable_stream(rs.stream.depth, *size, rs.format.z16, fps)
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(config)
        except RuntimeError as exc:  # no such camera, or it cannot stream this size and rate
            raise OSError(f"RealSense {self.serial or '(first found)'}: {exc}") from None
        self._pipeline = pipeline
        if self.depth:
            unit = profile.get_device().first_depth_sensor().get_depth_scale()
            spec = self.spec or DepthSpec(scale=unit)
            self._scale = spec
            self._align = rs.align(rs.stream.color) if spec.registered else None

    def read(self) -> tuple:
        try:
            frames = self._pipeline.wait_for_frames(FRAME_TIMEOUT_MS)
        except RuntimeError as exc:  # a timeout: unplugged, or the USB link dropped
            raise OSError(f"RealSense: no frames ({exc})") from None
        t_capture = time.monotonic()
        if self._align is not None:
            frames = self._align.process(frames)
        image = grey(np.asanyarray(frames.get_color_frame().get_data()))
        if not self.depth:
            return t_capture, t_capture, image
        return t_capture, t_capture, image, self._metres(frames.get_depth_frame())

    def _metres(self, raw: object) -> np.ndarray | UnreadableDepth | None:
        """The depth frame in metres in the colour pixels (None: the set had none)."""
        if not raw:
            return None
        try:
            return self._scale.to_metres(np.asanyarray(raw.get_data()), self.camera)
        except InputError as exc:  # not the size camera.yaml says: counted, image tracked
            return UnreadableDepth(str(exc))

    def close(self) -> None:
        if self._pipeline is not None:
            self._pipeline.stop()
            self._pipeline = None

