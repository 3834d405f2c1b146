"""`sdvl render PRESET --out DIR`: write a synthetic flight in the shared-data layout
(frames.txt, images/, camera.yaml, groundtruth.txt) plus imu.csv, sensors.csv and rig.yaml."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2

from calib.camera_yaml import save_camera
from sdvl.errors import InputError
from sim.datasets.layout import write_imu_csv, write_rig_yaml, write_sensors_csv
from sim.synth.flight import synthetic_sequence
from sim.synth.presets import PRESETS
from sim.trajectory import write_tum


def parse_size(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480); InputError otherwise."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must look like 640x480, got '{text}'") from None
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl render`."""
    parser.add_argument("preset", help=f"one of: {', '.join(PRESETS)}")
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--frames", type=int, help="only the first N frames")
    parser.add_argument("--size", help="image size WxH (default 640x480)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--textures", default="auto",
                        help="'auto' (shared photos if present), 'procedural', or a folder")


def run(args: argparse.Namespace) -> int:
    """Render every frame to PNG and write the ground truth and sensor files."""
    size = parse_size(args.size) if args.size else None
    seq = synthetic_sequence(args.preset, args.frames, size, args.seed, args.textures)
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise InputError("--out exists and is not a folder", out)
    (out / "images").mkdir(parents=True, exist_ok=True)
    save_camera(seq.camera, out / "camera.yaml",
                comment=f"sdvl render {args.preset} --seed {args.seed}")
    write_tum(seq.groundtruth, out / "groundtruth.txt")
    write_imu_csv(seq.imu, out / "imu.csv")
    write_sensors_csv(seq.extras["sensors"], out / "sensors.csv")
    write_rig_yaml(seq.extras["world"], seq.extras["T_b_c"], out / "rig.yaml")
    lines, start = [], time.monotonic()
    for i, (t, image) in enumerate(seq.frames()):
        name = f"images/{i:06d}.png"
        cv2.imwrite(str(out / name), image)
        lines.append(f"{t:.6f} {name}\n")
        if i % 30 == 29 or i + 1 == len(seq):
            rate = (i + 1) / max(time.monotonic() - start, 1e-9)
            print(f"\rrender {args.preset}: {i + 1}/{len(seq)} frames ({rate:.1f}/s)",
                  end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    (out / "frames.txt").write_text("# timestamp filename\n" + "".join(lines))
    print(f"wrote {len(seq)} frames to {out}")
    return 0
