"""`sdvl render PRESET --out DIR`: write a synthetic flight in the shared-data layout
(frames.txt, images/, camera.yaml, groundtruth.txt) plus imu.csv, sensors.csv and rig.yaml;
with --depth also depth.txt and depth/ (16-bit PNG in the sensor's unit, camera.yaml's
`depth` keys)."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from calib.camera_yaml import save_camera
from calib.depth_camera import DepthSpec
from sdvl.errors import InputError
from sim.datasets.layout import write_imu_csv, write_rig_yaml, write_sensors_csv
from sim.replay.progress import progress_bar
from sim.synth.depth_sensor import SENSORS, DepthSensor
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
    parser.add_argument("--depth", action="store_true",
                        help="also write depth maps (depth.txt, depth/*.png) as the preset's "
                             "depth camera measures them")
    parser.add_argument("--depth-sensor", choices=list(SENSORS), default=None,
                        help="the depth camera's error model (default: the preset's; "
                             "'ideal' has no noise and no holes)")


def depth_spec(sensor: DepthSensor) -> DepthSpec:
    """The camera.yaml `depth` keys of a rendered flight: registered, the sensor's range."""
    return DepthSpec(scale=sensor.unit_m or 0.001, min_m=sensor.min_m, max_m=sensor.max_m)


def run(args: argparse.Namespace) -> int:
    """Render every frame to PNG and write the ground truth and sensor files."""
    size = parse_size(args.size) if args.size else None
    if args.depth_sensor and not args.depth:
        raise InputError("--depth-sensor needs --depth")
    seq = synthetic_sequence(args.preset, args.frames, size, args.seed, args.textures,
                             depth=args.depth_sensor)
    sensor = seq.extras["depth_sensor"]
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise InputError("--out exists and is not a folder", out)
    (out / "images").mkdir(parents=True, exist_ok=True)
    spec = depth_spec(sensor) if args.depth else None
    if args.depth:
        (out / "depth").mkdir(exist_ok=True)
    save_camera(seq.camera, out / "camera.yaml",
                comment=f"sdvl render {args.preset} --seed {args.seed}"
                + (f" --depth (depth camera model {sensor.name})" if args.depth else ""),
                depth=spec)
    write_tum(seq.groundtruth, out / "groundtruth.txt")
    write_imu_csv(seq.imu, out / "imu.csv")
    write_sensors_csv(seq.extras["sensors"], out / "sensors.csv")
    write_rig_yaml(seq.extras["world"], seq.extras["T_b_c"], out / "rig.yaml")
    lines, depth_lines = [], []
    for i, (t, image) in enumerate(progress_bar(f"render {args.preset}", len(seq), seq.frames())):
        name = f"images/{i:06d}.png"
        cv2.imwrite(str(out / name), image)
        lines.append(f"{t:.6f} {name}\n")
        if args.depth:
            cv2.imwrite(str(out / f"depth/{i:06d}.png"), spec.to_raw(seq.depth(i)))
            depth_lines.append(f"{t:.6f} depth/{i:06d}.png\n")
    (out / "frames.txt").write_text("# timestamp filename\n" + "".join(lines))
    if args.depth:
        (out / "depth.txt").write_text("# timestamp filename\n" + "".join(depth_lines))
    print(f"wrote {len(seq)} frames to {out}")
    return 0
