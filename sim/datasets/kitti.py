"""KITTI odometry: sequences/NN/{image_0/, times.txt, calib.txt} and poses/NN.txt."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.camera import CameraModel
from sdvl.errors import InputError
from sdvl.textfile import check_increasing, parse_floats, read_lines, read_numeric_table
from sim.sequence import Sequence, image_list_sequence, load_grey
from sim.trajectory import Trajectory


def is_kitti(path: Path) -> bool:
    """True if `path` is a KITTI odometry sequence folder."""
    return (path / "image_0").is_dir() and (path / "times.txt").is_file()


def kitti_projection(calib: Path, key: str = "P0:") -> np.ndarray:
    """The 3x4 projection matrix `key` from a KITTI calib.txt."""
    for line, fields in read_lines(calib):
        if fields[0] == key:
            if len(fields) != 13:
                raise InputError(f"expected '{key}' and 12 numbers", calib, line)
            return np.array(parse_floats(fields[1:], calib, line, "12 numbers")).reshape(3, 4)
    raise InputError(f"no '{key}' line", calib)


def kitti_poses_path(path: Path) -> Path | None:
    """The ground-truth pose file of a sequence folder, wherever KITTI users keep it."""
    name = path.resolve().name
    for candidate in (path / "poses.txt", path / "poses" / f"{name}.txt",
                      path.resolve().parent.parent / "poses" / f"{name}.txt"):
        if candidate.is_file():
            return candidate
    return None


def read_kitti(path: Path, camera: CameraModel | None = None) -> Sequence:
    """A KITTI odometry sequence from the left grey camera, with its poses if found."""
    times = read_numeric_table(path / "times.txt", 1, "one timestamp")[:, 0]
    check_increasing(times, path / "times.txt")
    files = sorted((path / "image_0").glob("*.png"))
    if len(files) != len(times):
        raise InputError(f"{len(files)} images in image_0/ but {len(times)} lines in times.txt",
                         path)
    if camera is None:
        P = kitti_projection(path / "calib.txt")
        height, width = load_grey(files[0]).shape if files else (0, 0)
        camera = CameraModel(width, height, P[0, 0], P[1, 1], P[0, 2], P[1, 2])
    poses_path = kitti_poses_path(path)
    groundtruth = None
    if poses_path is not None:
        poses = read_numeric_table(poses_path, 12, "a 3x4 pose (12 numbers)")
        if len(poses) != len(times):
            raise InputError(f"{len(poses)} poses for {len(times)} frames", poses_path)
        groundtruth = Trajectory.from_matrices(times, poses.reshape(-1, 3, 4))
    return image_list_sequence(path.resolve().name, camera, times, files,
                               groundtruth=groundtruth, extras={"root": path})
