"""`sdvl run --config FILE`: the companion service (what systemd starts).

The signal handlers are installed first, before the slow imports (OpenCV, numba, the tracker),
so SIGTERM at any moment is a clean stop (exit code 0), and STOPPING=1 reaches systemd whichever
way the process ends. Exit codes: systemd/README.md.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from daemon.sdnotify import Notifier
from daemon.signals import EarlySignals, Stopped

if TYPE_CHECKING:  # the real imports are slow and come after the signal handlers
    from calib.camera import CameraModel
    from daemon.camera import FrameSource
    from daemon.config import CameraConfig, Config
    from daemon.frame_recorder import FrameRecorder
    from daemon.frames import Frame
    from daemon.service import Service

log = logging.getLogger("sdvl.service")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl run`."""
    parser.add_argument("--config", required=True, type=Path,
                        help="service config, TOML (every key: daemon/example_config.toml)")


def setup_logging(level: str) -> None:
    """One line per event on stderr; journald adds time and unit; a full disk drops lines
    (counted) rather than the service."""
    from daemon import logs

    logs.setup(level)


def quiet_opencv() -> None:
    """OpenCV's own warnings off: a bad frame is counted and logged once by the service, not
    once per frame by the decoder."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def open_source(cfg: CameraConfig) -> FrameSource:
    """The frame source a camera.source string names; with camera.depth, one that gives
    depth maps."""
    from sdvl.errors import InputError

    source = _named_source(cfg)
    if cfg.depth and not getattr(source, "depth", False):
        raise InputError(f"camera.depth is true but camera.source '{cfg.source}' gives no "
                         "depth maps: use a depth camera (\"realsense\") or set camera.depth "
                         "= false")
    return source


def _named_source(cfg: CameraConfig) -> FrameSource:
    """The source camera.source names: test pattern, RealSense, recording folder or OpenCV."""
    from calib.camera_yaml import load_camera
    from daemon.camera import OpenCVSource, RecordingSource, TestPatternSource
    from daemon.realsense import is_realsense
    from daemon.recordings import open_recording

    if cfg.source == "testpattern":
        return TestPatternSource(cfg.width or 320, cfg.height or 240, cfg.fps)
    if is_realsense(cfg.source):
        return realsense_source(cfg)
    if Path(cfg.source).is_dir():  # its depth maps are registered to camera.calibration's
        camera = load_camera(cfg.calibration) if cfg.calibration else None
        return RecordingSource(open_recording(cfg.source, cfg.fps, camera),
                               realtime=cfg.realtime, depth=cfg.depth)
    return OpenCVSource(cfg.source, cfg.width, cfg.height, cfg.fps, cfg.realtime)


def realsense_source(cfg: CameraConfig) -> FrameSource:
    """A RealSense camera (daemon/realsense.py) with camera.calibration's intrinsics and
    depth keys."""
    from calib.camera_yaml import load_camera, load_depth_spec
    from daemon.realsense import RealSenseSource
    from sdvl.errors import InputError

    if not cfg.calibration:
        raise InputError(f"camera.calibration: set the path of a camera.yaml for "
                         f"'{cfg.source}' (its colour intrinsics: rs-enumerate-devices -c)")
    camera = fit_camera(load_camera(cfg.calibration), cfg.width, cfg.height) \
        if cfg.width and cfg.height else load_camera(cfg.calibration)
    return RealSenseSource(cfg.source, camera, load_depth_spec(cfg.calibration), cfg.fps,
                           cfg.depth)


def camera_model(cfg: CameraConfig, source: FrameSource) -> CameraModel:
    """Intrinsics from camera.calibration, else the ones the source brings; a configured
    capture size the calibration does not fit is an InputError now, not after the start."""
    from calib.camera_yaml import load_camera
    from sdvl.errors import InputError

    if cfg.calibration:
        camera = load_camera(cfg.calibration)
    elif source.camera is None:
        raise InputError(f"camera.calibration: set the path of a camera.yaml for '{cfg.source}'")
    else:
        camera = source.camera
    if cfg.width and cfg.height:
        fit_camera(camera, cfg.width, cfg.height)
    return camera


def fit_camera(camera: CameraModel, width: int, height: int) -> CameraModel:
    """The model for frames of this size: the calibration itself or uniformly scaled."""
    from sdvl.errors import InputError

    if (camera.width, camera.height) == (width, height):
        return camera
    factor = width / camera.width
    if abs(camera.height * factor - height) > 0.5:
        raise InputError(f"frames are {width}x{height} but the calibration is "
                         f"{camera.width}x{camera.height}: calibrate at this size")
    return camera.scaled(factor)


def frame_recorder(cfg: CameraConfig, camera: CameraModel) -> FrameRecorder | None:
    """The recorder camera.record asks for (None: off), writing the frames' intrinsics."""
    if not cfg.record:
        return None
    from daemon.frame_recorder import FrameRecorder

    return FrameRecorder(Path(cfg.record), lambda width, height: fit_camera(camera, width,
                                                                             height), cfg.depth)


def tracker_factory(config: Config, camera: CameraModel,
                    warm_first: bool = False) -> Callable[[Frame], object]:
    """Builds the tracker on the first frame (its results carry the matched map points for
    fusion); tracker options are validated now. `warm_first`: before the first tracker, warm
    a throwaway one up at the frame's size (warm_up), in the tracking thread."""
    from sdvl.errors import InputError

    try:
        from vo.config import TrackerConfig
        from vo.tracker import Tracker
    except ImportError as exc:
        raise InputError(f"the tracker (vo) is not installed: {exc}") from None
    from daemon.fusion.scene import SceneTracker

    # the service sends each frame's pose as it comes: poses given late (vo.late_poses) would
    # only cost time on the map's first frame
    tracker_config = replace(TrackerConfig.from_dict(config.tracker), init_late_poses=0)

    def make(frame: Frame) -> object:
        height, width = frame.image.shape[:2]
        tracker = Tracker(fit_camera(camera, width, height), tracker_config,
                          threaded=config.service.mapping_thread)
        # a depth camera's maps start only from depth, also while its first frames have none
        # (on the ground, nearer than its minimum range): never a monocular map of unknown scale
        tracker.depth_mode = config.camera.depth and tracker_config.depth
        return SceneTracker(tracker)

    if not warm_first:
        return make
    warmed = False  # only the tracking thread builds trackers

    def warm_then_make(frame: Frame) -> object:
        nonlocal warmed
        if not warmed:
            height, width = frame.image.shape[:2]
            log.info("warming the tracker up (the first start after an install compiles its "
                     "kernels: a minute or more on a small computer)")
            log.info("tracker warmed up in %.1f s", warm_up(make, width, height))
            warmed = True
        return make(frame)

    return warm_then_make


def warm_up(make_tracker: Callable[[Frame], object], width: int, height: int) -> float:
    """Run a throwaway tracker over the tracker's warm-up frames (vo.warm_up: a synthetic pan
    of width x height, nothing rendered or read) so that every kernel is compiled or loaded
    before the first real frame (not mid-flight, where a cold cache stalled tracking 1-2 s and
    lost it); returns the seconds it took."""
    import numpy as np

    from daemon.frames import Frame
    from vo.warm_up import warm_up as warm_tracker

    start = time.perf_counter()
    tracker = make_tracker(Frame(0, 0.0, time.monotonic(), np.zeros((height, width), np.uint8)))
    try:
        warm_tracker(tracker.process, width, height)
    finally:
        tracker.close()
    return time.perf_counter() - start


async def serve(service: Service, signals: EarlySignals | None = None,
                reread: Callable[[], Config] | None = None) -> int:
    """Run the service; SIGTERM/SIGINT stop it cleanly, SIGHUP rereads the configuration
    (`reread`, an InputError keeps the running one)."""
    from sdvl.errors import InputError

    def reload() -> None:
        service.notifier.reloading()
        try:
            service.reload(reread())
        except InputError as exc:
            log.error("SIGHUP: %s; the running configuration is kept", exc)
        service.notifier.notify("READY=1")

    (signals or EarlySignals()).hand_over(asyncio.get_running_loop(), service.stop, reload)
    return await service.run()


def run(args: argparse.Namespace) -> int:
    """Entry point of `sdvl run`; once the service ran, the process ends here (exit_now)."""
    notifier = Notifier()
    signals = EarlySignals()
    try:
        signals.install()  # inside: a SIGTERM between its first and last handler is a stop too
        code = _start(args, signals, notifier)
    except Stopped:  # SIGTERM/SIGINT while starting: a clean stop
        return 0
    finally:
        signals.finish()
        notifier.stopping()
    exit_now(code)


def _start(args: argparse.Namespace, signals: EarlySignals, notifier: Notifier) -> int:
    from daemon import numba_cache
    from daemon.config import load_config
    from daemon.service import Service, prefer_handoffs

    config = load_config(args.config)
    setup_logging(config.service.log_level)
    quiet_opencv()
    source = open_source(config.camera)
    camera = camera_model(config.camera, source)
    numba_cache.prepare()
    service = Service(config, source, tracker_factory(config, camera, warm_first=True),
                      notifier=notifier,
                      size_ok=lambda width, height: fit_camera(camera, width, height),
                      recorder=frame_recorder(config.camera, camera))
    prefer_handoffs()
    return asyncio.run(serve(service, signals, lambda: load_config(args.config)))


def exit_now(code: int) -> NoReturn:
    """End the process once the service has stopped (STOPPING=1 sent, logs flushed), without
    the interpreter's final garbage collection: freeing the tracker's maps and numba's
    compiled kernels took 3-5 s on a loaded 2-core machine, close to systemd's TimeoutStopSec
    (5 s), after which it kills the service and marks it failed."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
