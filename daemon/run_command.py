"""`sdvl run --config FILE`: the companion service (what systemd starts)."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from collections.abc import Callable
from pathlib import Path

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from daemon.camera import FrameSource, OpenCVSource, SequenceSource, TestPatternSource
from daemon.config import CameraConfig, Config, load_config
from daemon.frames import Frame
from daemon.recordings import open_recording
from daemon.service import Service
from sdvl.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl run`."""
    parser.add_argument("--config", required=True, type=Path,
                        help="service config, TOML (every key: daemon/example_config.toml)")


def setup_logging(level: str) -> None:
    """One line per event on stderr; journald adds time and unit."""
    logging.basicConfig(stream=sys.stderr, level=level.upper(), force=True,
                        format="%(levelname)s %(name)s: %(message)s")


def open_source(cfg: CameraConfig) -> FrameSource:
    """The frame source a camera.source string names."""
    if cfg.source == "testpattern":
        return TestPatternSource(cfg.width or 320, cfg.height or 240, cfg.fps)
    if Path(cfg.source).is_dir():
        return SequenceSource(open_recording(cfg.source, cfg.fps), realtime=cfg.realtime)
    return OpenCVSource(cfg.source, cfg.width, cfg.height, cfg.fps, cfg.realtime)


def camera_model(cfg: CameraConfig, source: FrameSource) -> CameraModel:
    """Intrinsics from camera.calibration, else the ones the source brings."""
    if cfg.calibration:
        return load_camera(cfg.calibration)
    if source.camera is None:
        raise InputError(f"camera.calibration: set the path of a camera.yaml for '{cfg.source}'")
    return source.camera


def fit_camera(camera: CameraModel, width: int, height: int) -> CameraModel:
    """The model for frames of this size: the calibration itself or uniformly scaled."""
    if (camera.width, camera.height) == (width, height):
        return camera
    factor = width / camera.width
    if abs(camera.height * factor - height) > 0.5:
        raise InputError(f"frames are {width}x{height} but the calibration is "
                         f"{camera.width}x{camera.height}: calibrate at this size")
    return camera.scaled(factor)


def tracker_factory(config: Config, camera: CameraModel) -> Callable[[Frame], object]:
    """Builds the tracker on the first frame (its results carry the matched map points for
    fusion); tracker options are validated now."""
    try:
        from vo.config import TrackerConfig
        from vo.tracker import Tracker
    except ImportError as exc:
        raise InputError(f"the tracker (vo) is not installed: {exc}") from None
    from daemon.fusion.scene import SceneTracker

    tracker_config = TrackerConfig.from_dict(config.tracker)

    def make(frame: Frame) -> object:
        height, width = frame.image.shape[:2]
        return SceneTracker(Tracker(fit_camera(camera, width, height), tracker_config,
                                    threaded=config.service.mapping_thread))

    return make


async def serve(service: Service) -> int:
    """Run the service with SIGTERM/SIGINT stopping it cleanly."""
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, service.stop)
    return await service.run()


def run(args: argparse.Namespace) -> int:
    """Entry point of `sdvl run`."""
    config = load_config(args.config)
    setup_logging(config.service.log_level)
    source = open_source(config.camera)
    make_tracker = tracker_factory(config, camera_model(config.camera, source))
    return asyncio.run(serve(Service(config, source, make_tracker)))
