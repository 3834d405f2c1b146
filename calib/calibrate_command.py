"""`sdvl calibrate`: calibrate a camera from board images, a video or a live device, or convert
a calibration file between formats (`--convert IN --to FORMAT --out OUT`).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import re
import sys
from datetime import UTC, datetime
from pathlib import Path

import cv2

from calib.board import BOARD_KINDS, BoardDetector, BoardSpec
from calib.calibration import MODELS
from calib.camera_yaml import save_camera
from calib.coverage import corner_coverage, draw_coverage
from calib.formats import FORMATS, format_help, read_camera_file, write_camera_file
from calib.frame_sources import device_frames, image_files, video_frames
from calib.report import CalibrationReport
from calib.view_collection import CollectedViews, collect_views, thin_views
from calib.view_quality import DEFAULT_MAX_BLUR_PX
from calib.view_selection import (
    DEFAULT_MIN_VIEWS,
    DEFAULT_OUTLIER_FACTOR,
    MotionGate,
    calibrate_robustly,
)
from sdvl.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl calibrate`."""
    parser.description = (
        "Calibrate a camera from images of a chessboard or ChArUco board and write the "
        "camera.yaml the tracker and the service read; or convert a calibration file "
        "(Kalibr, ROS, OpenCV, ORB-SLAM, original SDVL) with --convert.")
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = (
        "examples:\n"
        "  sdvl calibrate shots/*.jpg --cols 9 --rows 6 --square 0.025 --out camera.yaml\n"
        "  sdvl calibrate --device 0 --board charuco --cols 8 --rows 6 --square 0.035 "
        "--marker 0.026 --model fisheye\n"
        "  sdvl calibrate --convert camchain.yaml --to sdvl --out camera.yaml")
    src = parser.add_argument_group("input (one of)")
    src.add_argument("images", nargs="*", metavar="IMAGE", help="board images (PNG, JPEG ...)")
    src.add_argument("--video", metavar="FILE", help="a video of the board being moved")
    src.add_argument("--device", type=int, metavar="N",
                     help="live camera /dev/videoN; keeps a frame when the board has moved; "
                          "Ctrl-C to finish early")
    src.add_argument("--convert", metavar="FILE",
                     help="convert this calibration file instead of calibrating")
    board = parser.add_argument_group("board")
    board.add_argument("--board", choices=BOARD_KINDS, default="chessboard")
    board.add_argument("--cols", type=int, help="chessboard: inner corners across; "
                                                "charuco: squares across")
    board.add_argument("--rows", type=int, help="chessboard: inner corners down; "
                                                "charuco: squares down")
    board.add_argument("--square", type=float, metavar="METRES", help="square side length")
    board.add_argument("--marker", type=float, metavar="METRES",
                       help="charuco marker side (default 0.75 x square)")
    board.add_argument("--dictionary", default="DICT_5X5_100", help="charuco ArUco dictionary")
    board.add_argument("--legacy-charuco", action="store_true",
                       help="board made with OpenCV < 4.6 (different layout for even rows)")
    calib = parser.add_argument_group("calibration")
    calib.add_argument("--model", choices=tuple(MODELS), default="pinhole-radtan")
    calib.add_argument("--min-views", type=int, default=DEFAULT_MIN_VIEWS,
                       help="fewest good views to calibrate from (default %(default)s)")
    calib.add_argument("--max-blur", type=float, default=DEFAULT_MAX_BLUR_PX, metavar="PX",
                       help="skip views whose board edges are wider (default %(default)s px)")
    calib.add_argument("--outlier-factor", type=float, default=DEFAULT_OUTLIER_FACTOR,
                       help="reject views with RMS error above this x the median "
                            "(default %(default)s)")
    calib.add_argument("--min-move", type=float, default=0.03, metavar="FRACTION",
                       help="video/device: keep a frame when the board moved this fraction "
                            "of the image diagonal from every kept view (default %(default)s)")
    calib.add_argument("--max-views", type=int, default=40,
                       help="video/device: calibrate from at most this many views "
                            "(default %(default)s)")
    calib.add_argument("--save-views", metavar="DIR",
                       help="video/device: save the kept frames here as PNG")
    out = parser.add_argument_group("output")
    out.add_argument("--out", default="camera.yaml", help="camera file (default %(default)s)")
    out.add_argument("--to", choices=tuple(FORMATS), default="sdvl",
                     help="format of --out; " + format_help())
    out.add_argument("--from", dest="from_format", choices=tuple(FORMATS),
                     help="--convert: format of the input (default: guessed from its keys)")
    out.add_argument("--coverage", metavar="PNG",
                     help="coverage picture (default: next to --out, *_coverage.png)")
    out.add_argument("--json", action="store_true", help="print the report as JSON")


def _log(message: str) -> None:
    print(f"sdvl calibrate: {message}", file=sys.stderr, flush=True)


def _convert(args: argparse.Namespace) -> int:
    if args.images or args.video or args.device is not None:
        raise InputError("--convert takes no images, --video or --device")
    camera, fmt = read_camera_file(args.convert, args.from_format)
    write_camera_file(camera, args.out, args.to)
    print(f"wrote {args.out} ({args.to}) from {args.convert} ({fmt}): {camera.width}x"
          f"{camera.height} {camera.distortion_model} fx {camera.fx:.3f} fy {camera.fy:.3f} "
          f"cx {camera.cx:.3f} cy {camera.cy:.3f}")
    return 0


def _spec(args: argparse.Namespace) -> BoardSpec:
    missing = [f"--{n}" for n in ("cols", "rows", "square") if getattr(args, n) is None]
    if missing:
        raise InputError(f"the board needs {', '.join(missing)} (e.g. --board chessboard "
                         "--cols 9 --rows 6 --square 0.025)")
    return BoardSpec(args.board, args.cols, args.rows, args.square, args.marker,
                     args.dictionary, args.legacy_charuco)


def _collect(args: argparse.Namespace, spec: BoardSpec) -> CollectedViews:
    sources = [bool(args.images), args.video is not None, args.device is not None]
    if sum(sources) != 1:
        raise InputError("give board images, or --video FILE, or --device N (exactly one); "
                         "or --convert FILE to convert a calibration file")
    if args.images:
        if args.save_views:
            raise InputError("--save-views is for --video and --device (images are files already)")
        return collect_views(image_files(args.images), BoardDetector(spec), args.max_blur)
    frames = video_frames(args.video) if args.video else device_frames(args.device)
    first = next(frames, None)
    if first is None:
        raise InputError("no frames could be read", args.video or f"device {args.device}")
    diagonal = math.hypot(*first[1].shape[:2])
    if args.device is not None:
        _log("move the board to a new place, distance and angle and hold it still; "
             f"Ctrl-C to finish before {args.max_views} views")
    collected = collect_views(
        itertools.chain([first], frames), BoardDetector(spec, thorough=False), args.max_blur,
        gate=MotionGate(args.min_move * diagonal),
        stop_after=args.max_views if args.device is not None else None,
        keep_images=args.save_views is not None, log=_log)
    summary = ", ".join(f"{k} {n}" for k, n in collected.counts.items() if k != "frames")
    _log(f"{collected.counts['frames']} frames read, {len(collected.views)} views kept"
         + (f"; not kept: {summary}" if summary else ""))
    collected.views = thin_views(collected.views, args.max_views)
    return collected


def _save_views(collected: CollectedViews, folder: str) -> None:
    Path(folder).mkdir(parents=True, exist_ok=True)
    for view in collected.views:
        name = re.sub(r"[^\w.-]", "_", view.name) + ".png"
        if not cv2.imwrite(str(Path(folder) / name), collected.images[view.name]):
            raise InputError("cannot write image", Path(folder) / name)


def _write_camera(report: CalibrationReport, args: argparse.Namespace) -> None:
    camera = report.calibration.result.camera
    if args.to != "sdvl":
        write_camera_file(camera, args.out, args.to)
        return
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    save_camera(camera, args.out, comment=(
        f"sdvl calibrate, {stamp}: {report.model}, {report.board.describe()}\n"
        f"RMS {report.calibration.result.rms:.3f} px over {len(report.calibration.views)} "
        f"views, {report.coverage.fraction:.0%} image coverage, verdict {report.verdict}"))


def run(args: argparse.Namespace) -> int:
    """Calibrate (or convert), write the camera file and the coverage picture, print a report."""
    if args.convert:
        return _convert(args)
    spec = _spec(args)
    if args.min_views < 3 or args.max_views < args.min_views:
        raise InputError(f"need 3 <= --min-views <= --max-views, got {args.min_views} and "
                         f"{args.max_views}")
    collected = _collect(args, spec)
    for name, reason in collected.skipped:
        _log(f"skipped {name}: {reason}")
    if collected.size is None:
        raise InputError("none of the images could be read")
    if args.save_views:
        _save_views(collected, args.save_views)
    robust = calibrate_robustly(collected.views, collected.size, args.model, args.min_views,
                                args.outlier_factor)
    points = [v.detection.image_points for v in robust.views]
    coverage = corner_coverage(points, collected.size)
    report = CalibrationReport(spec, args.model, robust, coverage, collected.skipped)
    coverage_path = args.coverage or str(Path(args.out).with_name(
        Path(args.out).stem + "_coverage.png"))
    draw_coverage(points, coverage, coverage_path)
    _write_camera(report, args)
    if args.json:
        print(json.dumps({**report.to_dict(), "out": args.out, "coverage_png": coverage_path},
                         indent=2))
    else:
        print(report.to_text())
        print(f"wrote {args.out} ({args.to}) and {coverage_path}")
    return 0
