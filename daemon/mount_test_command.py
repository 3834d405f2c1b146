"""`sdvl mount-test --config FILE`: check the camera mounting on the bench (see mount_test.py)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from daemon.config import load_config
from daemon.frames import Frame
from daemon.mount_test import MountTest
from daemon.run_command import camera_model, open_source, tracker_factory
from sdvl.errors import InputError

INSTRUCTIONS = ("Mount self-test: hold the vehicle level, then move it slowly by hand\n"
                "  1. forward (towards its nose)  -> expect FORWARD\n"
                "  2. to its right                -> expect RIGHT\n"
                "  3. lift it up                  -> expect UP\n"
                "Anything else: fix [mounting] in the config. Ctrl-C to stop.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl mount-test`."""
    parser.add_argument("--config", required=True, type=Path,
                        help="service config, TOML: camera and [mounting] are used")
    parser.add_argument("--seconds", type=float, default=0.0,
                        help="stop after this long (default: until Ctrl-C or the source ends)")
    parser.add_argument("--min-move", type=float, default=0.1,
                        help="motion, in tracker units (about scene depths), before a reading")
    parser.add_argument("--interval", type=float, default=0.5,
                        help="seconds between printed readings")


def run(args: argparse.Namespace) -> int:
    """Print the body-frame motion the camera sees until stopped."""
    config = load_config(args.config)
    source = open_source(config.camera)
    make_tracker = tracker_factory(config, camera_model(config.camera, source))
    test = MountTest(config.mounting, args.min_move)
    print(INSTRUCTIONS, flush=True)
    try:
        source.open()
    except OSError as exc:
        raise InputError(f"camera.source '{config.camera.source}' cannot be opened: {exc}",
                         args.config) from None
    tracker, index, last_print = None, 0, float("-inf")
    start = time.monotonic()
    try:
        while not args.seconds or time.monotonic() - start < args.seconds:
            item = source.read()
            if item is None:
                break
            t_source, t_capture, image = item
            if tracker is None:
                tracker = make_tracker(Frame(index, t_source, t_capture, image))
            index += 1
            reading = test.on_result(tracker.process(image, t_source))
            if reading is not None and time.monotonic() - last_print >= args.interval:
                print(reading.line(), flush=True)
                last_print = time.monotonic()
    finally:
        source.close()
        if tracker is not None:
            tracker.close()
    return 0
