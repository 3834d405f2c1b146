"""`sdvl map SEQUENCE --out FILE`: fuse a sequence's depth maps along metric camera poses into
a 3D occupancy map (vo.occupancy) and write it as OctoMap .bt / .ot or as a .ply point cloud
(daemon.map_files); with --score (synthetic presets) compare it with the scene."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from calib.depth_camera import decimate, points_from_depth, unit_depth_rays
from daemon.map_files import MAP_SUFFIXES, write_map
from sdvl.errors import InputError
from sim.replay.progress import progress_bar
from sim.track_methods import METHODS, alignment, check_method, load_config
from sim.trajectory import Trajectory, read_tum
from vo.occupancy import OccupancyMap, OccupancySettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl map`."""
    parser.add_argument("sequence", help="a sequence with depth (depth.txt) or a synthetic preset")
    parser.add_argument("--out", required=True, type=Path,
                        help=f"the map file: {', '.join(MAP_SUFFIXES)} (OctoMap binary, OctoMap "
                             "full, PLY point cloud of the occupied voxels)")
    metric = [m for m, a in METHODS.items() if a == "se3"]
    parser.add_argument("--poses", default=metric[0],
                        help=f"camera poses: a metric tracker ({', '.join(metric)}; default "
                             f"{metric[0]}), 'groundtruth', or a TUM trajectory file of "
                             "world-from-camera poses in metres")
    parser.add_argument("--voxel", type=float, default=OccupancySettings.voxel_m, metavar="M",
                        help=f"voxel size in metres (default {OccupancySettings.voxel_m})")
    parser.add_argument("--max-range", type=float, default=0.0, metavar="M",
                        help="fuse measurements up to this far (longer rays only clear space "
                             "up to it; default 0: all the depth camera gives)")
    parser.add_argument("--decimate", type=int, default=4, metavar="N",
                        help="average the depth over N x N pixel blocks first, as depth "
                             "cameras' decimation filters do (default 4: 640x480 -> 160x120)")
    parser.add_argument("--every", type=int, default=1, metavar="N",
                        help="fuse every N-th frame (default 1)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N")
    parser.add_argument("--size", default=None, metavar="WxH",
                        help="image size for a synthetic preset (default: the preset's)")
    parser.add_argument("--depth-sensor", default=None, metavar="NAME",
                        help="synthetic presets: the depth camera model (sim.synth."
                             "depth_sensor: d435, d455, kinect-v1, ideal; default the preset's)")
    parser.add_argument("--score", action="store_true",
                        help="synthetic presets: precision and recall of the occupied voxels "
                             "against the scene (a tracker's poses are first aligned to the "
                             "ground truth, SE(3))")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run(args: argparse.Namespace) -> int:
    """Fuse, write, report."""
    check_arguments(args)
    sequence = open_map_sequence(args.sequence, args.size, args.depth_sensor)
    if not sequence.has_depth:
        raise InputError(f"sequence '{sequence.name}' has no depth maps (a depth.txt beside its "
                         "frame list, or a synthetic preset)")
    poses, mask = frame_poses(sequence, args.poses, args.max_frames, args.quiet, args.score)
    settings = OccupancySettings(voxel_m=args.voxel, max_range_m=args.max_range)
    occupancy, report = fuse(sequence, poses, mask, settings, args.decimate, args.every,
                             args.quiet)
    start = time.perf_counter()
    write_map(occupancy, args.out)
    report.update(out=str(args.out), write_ms=(time.perf_counter() - start) * 1e3,
                  file_bytes=args.out.stat().st_size)
    if args.score:
        report["score"] = scene_score(sequence, occupancy, mask, args.decimate,
                                      args.every).to_dict()
    print(json.dumps(report) if args.json else format_report(report))
    return 0


def check_arguments(args: argparse.Namespace) -> None:
    """InputError for values out of range."""
    if not args.voxel > 0:
        raise InputError("--voxel must be positive")
    if args.max_range < 0:
        raise InputError("--max-range must be 0 (no limit) or positive")
    if args.decimate < 1 or args.every < 1:
        raise InputError("--decimate and --every must be at least 1")
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    if args.out.suffix.lower() not in MAP_SUFFIXES:
        raise InputError(f"--out must end in {', '.join(MAP_SUFFIXES)}", args.out)


def open_map_sequence(name: str, size: str | None, sensor: str | None):
    """The sequence by path, shared-data name or preset (`size` and `sensor` for presets)."""
    from sim.track_command import resolve_sequence

    if size is None and sensor is None:
        return resolve_sequence(name)
    from sim.render_command import parse_size
    from sim.synth.flight import synthetic_sequence
    from sim.synth.presets import PRESETS

    if name not in PRESETS:
        raise InputError(f"--size and --depth-sensor are for synthetic presets "
                         f"({', '.join(PRESETS)})")
    return synthetic_sequence(name, size=parse_size(size) if size else None, depth=sensor)


def frame_poses(sequence, source: str, max_frames: int | None, quiet: bool,
                to_groundtruth: bool) -> tuple[np.ndarray, np.ndarray]:
    """T_w_c (N, 4, 4) at the first N frames and the mask of frames that have one, from
    `source` (see --poses); a tracker's poses are SE(3)-aligned to the ground truth when
    `to_groundtruth`."""
    from sim.metrics import align_trajectories, interpolate

    n = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    if source == "groundtruth":
        if sequence.groundtruth is None:
            raise InputError(f"sequence '{sequence.name}' has no ground truth")
        trajectory = sequence.groundtruth
    elif source in METHODS:
        trajectory = tracked(sequence, source, n, quiet)
        if to_groundtruth and sequence.groundtruth is not None:
            trajectory = align_trajectories(sequence.groundtruth, trajectory, "se3").estimate
    else:
        trajectory = read_tum(source)
    poses, mask = interpolate(trajectory, sequence.timestamps[:n])
    if not mask.any():
        raise InputError(f"no pose of '{source}' falls within the sequence's frame times")
    full = np.tile(np.eye(4), (n, 1, 1))
    full[mask] = poses.matrices()
    return full, mask


def tracked(sequence, method: str, n: int, quiet: bool) -> Trajectory:
    """The trajectory a metric tracker gives over the first n frames."""
    from sim.track_command import track_sequence

    check_method(method, sequence)
    if alignment(method) != "se3":
        raise InputError(f"--poses {method}: a monocular tracker's poses have no metric scale "
                         "(use a depth tracker, groundtruth or a metric trajectory file)")
    _, estimate = track_sequence(sequence, load_config(method, None), False, n, quiet,
                                 method=method)
    if estimate is None:
        raise InputError(f"{method} tracked no frame of '{sequence.name}'")
    return estimate


def fuse(sequence, poses: np.ndarray, mask: np.ndarray, settings: OccupancySettings,
         factor: int, every: int, quiet: bool) -> tuple[OccupancyMap, dict]:
    """The occupancy map of every `every`-th posed frame's depth map (decimated by `factor`),
    and a report: frames fused, per-frame fusion time (median, p95 ms), voxels, memory."""
    occupancy = OccupancyMap(settings)
    rays = None
    times = []
    frames = np.flatnonzero(mask)[::every]
    for i in progress_bar("fuse", len(frames), frames, enabled=not quiet):
        depth = sequence.depth(int(i))
        if depth is None:
            continue
        depth, camera = decimate(depth, sequence.camera, factor)
        rays = unit_depth_rays(camera) if rays is None else rays
        points, _ = points_from_depth(depth, camera, rays)
        T = poses[i]
        start = time.perf_counter()
        occupancy.insert(points @ T[:3, :3].T + T[:3, 3], T[:3, 3])
        times.append((time.perf_counter() - start) * 1e3)
    _, logodds = occupancy.voxels()
    return occupancy, {
        "sequence": sequence.name, "frames_fused": len(times), "voxel_m": settings.voxel_m,
        "fuse_ms_median": float(np.median(times)) if times else None,
        "fuse_ms_p95": float(np.percentile(times, 95)) if times else None,
        "voxels_occupied": int((logodds > 0).sum()), "voxels_free": int((logodds <= 0).sum()),
        "map_mb": occupancy.memory_bytes() / 2**20}


def scene_score(sequence, occupancy: OccupancyMap, mask: np.ndarray, factor: int,
                every: int):
    """MapScore of the map against the synthetic scene (see sim.map_scoring)."""
    from sim.map_scoring import score_map, seen_voxels

    renderer = sequence.image_loader
    if "preset" not in sequence.extras or not hasattr(renderer, "surfaces"):
        raise InputError("--score compares with the scene of a synthetic preset: give a "
                         "preset name")
    sensor = sequence.extras["depth_sensor"]
    seen, rays = [], None
    truth = sequence.groundtruth
    poses = truth.matrices()
    for i in np.flatnonzero(mask)[::every]:
        t = float(sequence.timestamps[i])
        depth = renderer.surfaces(t).depth.copy()
        depth[~((depth >= sensor.min_m) & (depth <= sensor.max_m))] = 0.0
        depth, camera = decimate(depth, sequence.camera, factor)
        rays = unit_depth_rays(camera) if rays is None else rays
        points, _ = points_from_depth(depth, camera, rays)
        T = poses[np.searchsorted(truth.t, t)]
        seen.append(seen_voxels(points @ T[:3, :3].T + T[:3, 3], occupancy.settings.voxel_m))
    scene = renderer.spec.scene.quads_at(float(sequence.timestamps[0]))
    return score_map(occupancy.occupied(), scene, np.vstack(seen), occupancy.settings.voxel_m)


def format_report(r: dict) -> str:
    """Human-readable lines of a report."""
    lines = [f"sequence   {r['sequence']}",
             f"fused      {r['frames_fused']} frames, {r['fuse_ms_median']:.1f} ms median, "
             f"{r['fuse_ms_p95']:.1f} ms p95 per frame",
             f"voxels     {r['voxels_occupied']} occupied, {r['voxels_free']} free "
             f"({r['voxel_m']} m), {r['map_mb']:.1f} MB in memory",
             f"wrote      {r['out']} ({r['file_bytes'] / 1024:.0f} KiB, {r['write_ms']:.0f} ms)"]
    if "score" in r:
        s = r["score"]
        lines.append(f"score      precision {s['precision']:.3f} ({s['occupied_on_surface']}/"
                     f"{s['occupied']} occupied voxels on a surface), recall {s['recall']:.3f} "
                     f"({s['seen_recalled']}/{s['seen_surface']} seen surface voxels)")
    return "\n".join(lines)
