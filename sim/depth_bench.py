"""`python -m sim.depth_bench [PRESET] [--frames N] [--every K]`: what depth costs per frame.

Per stage, median and p95 ms over the frames of a synthetic flight with simulated depth:
obstacle sectors from one depth image (daemon.obstacles), fusing one depth image into the
occupancy map with this project's numba kernel (vo.occupancy) and, on the same points, with
the OctoMap library's own insertPointCloud (octomap-python); then the two maps' memory, and
the time and size of each map file format. This is what `sdvl map` chose its integrator and
formats by.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from calib.depth_camera import decimate, points_from_depth, unit_depth_rays
from daemon.map_files import MAP_SUFFIXES, write_map
from daemon.obstacles import ObstacleDistances, ObstacleSettings
from sim.track_command import stage_stats
from vo.occupancy import OccupancyMap, OccupancySettings


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print its table."""
    import octomap

    from sim.synth.flight import synthetic_sequence

    parser = argparse.ArgumentParser(prog="python -m sim.depth_bench", description=__doc__)
    parser.add_argument("preset", nargs="?", default="room-handheld")
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--every", type=int, default=4, help="use every K-th frame")
    parser.add_argument("--decimate", type=int, default=4)
    args = parser.parse_args(argv)
    seq = synthetic_sequence(args.preset, args.frames)
    sensor = seq.extras["depth_sensor"]
    obstacles = ObstacleDistances(seq.camera, seq.extras["T_b_c"],
                                  ObstacleSettings(min_m=sensor.min_m, max_m=sensor.max_m))
    ours, tree = OccupancyMap(OccupancySettings()), octomap.OcTree(OccupancySettings.voxel_m)
    rays, timings = None, []
    poses = seq.groundtruth.matrices()
    for i in range(0, len(seq), args.every):
        depth = seq.depth(i)
        times = {}
        start = time.perf_counter()
        obstacles.scan(depth, seq.timestamps[i])
        times["obstacles"] = ms(start)
        small, camera = decimate(depth, seq.camera, args.decimate)
        rays = unit_depth_rays(camera) if rays is None else rays
        points, _ = points_from_depth(small, camera, rays)
        world = points @ poses[i][:3, :3].T + poses[i][:3, 3]
        start = time.perf_counter()
        ours.insert(world, poses[i][:3, 3])
        times["fuse numba"] = ms(start)
        start = time.perf_counter()
        tree.insertPointCloud(world, poses[i][:3, 3])
        times["fuse octomap"] = ms(start)
        timings.append(times)
    print(f"{args.preset}: {len(timings)} frames, {seq.camera.width}x{seq.camera.height}, "
          f"depth decimated by {args.decimate} ({len(points)} points in the last frame)")
    print("stage              median ms    p95 ms")
    for name, s in stage_stats(timings).items():
        print(f"{name:<18} {s['median']:9.2f} {s['p95']:9.2f}")
    print(f"memory             numba {ours.memory_bytes() / 2**20:.1f} MiB, "
          f"octomap {tree.memoryUsage() / 2**20:.1f} MiB")
    print_files(ours)
    return 0


def print_files(occupancy: OccupancyMap) -> None:
    """Time and size of writing the map in each format."""
    with tempfile.TemporaryDirectory() as folder:
        for suffix in MAP_SUFFIXES:
            path = Path(folder) / f"map{suffix}"
            start = time.perf_counter()
            write_map(occupancy, path)
            size = path.stat().st_size / 1024
            print(f"write {suffix:<4}         {ms(start):9.0f} ms {size:9.0f} KiB")


def ms(start: float) -> float:
    """Milliseconds since `start` (perf_counter)."""
    return (time.perf_counter() - start) * 1e3


if __name__ == "__main__":
    raise SystemExit(main())
