"""Occupancy maps (vo.occupancy) as files standard viewers open.

- `.bt`: OctoMap's binary tree, occupied / free only (octovis, ROS octomap_server and RViz's
  octomap plugin read it); `.ot`: OctoMap's full tree with each voxel's log-odds. Both are
  written by the OctoMap library itself through octomap-python (the optional extra
  `sdvl-companion[map]`).
- `.ply`: the occupied voxels' centres as a binary point cloud coloured by height (MeshLab,
  CloudCompare, Open3D, Blender), with no extra dependency.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from vo.occupancy import OccupancyMap

MAP_SUFFIXES = (".bt", ".ot", ".ply")


def write_map(occupancy: OccupancyMap, path: Path) -> None:
    """Write the map in the format its suffix names (MAP_SUFFIXES)."""
    suffix = path.suffix.lower()
    if suffix not in MAP_SUFFIXES:
        raise InputError(f"unknown map format '{suffix}' (use {', '.join(MAP_SUFFIXES)})", path)
    if suffix == ".ply":
        write_ply(occupancy.centres(occupancy.occupied()), path)
    else:
        tree = octree(occupancy, full=suffix == ".ot")
        ok = tree.write(str(path)) if suffix == ".ot" else tree.writeBinary(str(path))
        if not ok:
            raise InputError("OctoMap could not write the file", path)


def octomap_module():
    """The octomap-python module; InputError saying how to install it when it is missing."""
    try:
        import octomap
    except ImportError:
        raise InputError("writing OctoMap files (.bt, .ot) needs octomap-python: "
                         "pip install 'sdvl-companion[map]' (or write a .ply)") from None
    return octomap


def octree(occupancy: OccupancyMap, full: bool):
    """An octomap.OcTree with the map's voxels: with `full`, each voxel's log-odds; else
    occupied or free only (what a .bt keeps)."""
    octomap = octomap_module()
    s = occupancy.settings
    tree = octomap.OcTree(s.voxel_m)
    tree.setProbHit(s.prob_hit)
    tree.setProbMiss(s.prob_miss)
    tree.setClampingThresMin(s.clamp_min)
    tree.setClampingThresMax(s.clamp_max)
    keys, logodds = occupancy.voxels()
    centres = occupancy.centres(keys)
    if full:
        # a new node starts at log-odds 0: adding a voxel's value sets it (voxels of one value
        # at once; the values are sums of a few hit and miss steps, so there are few)
        values, group = np.unique(logodds, return_inverse=True)
        for k, value in enumerate(values):
            tree.updateNodes(centres[group == k], float(value), True)
    else:
        tree.updateNodes(centres[logodds > 0], True, True)
        tree.updateNodes(centres[logodds <= 0], False, True)
    tree.updateInnerOccupancy()
    return tree


def write_ply(points: np.ndarray, path: Path) -> None:
    """Points (N, 3) as a binary little-endian PLY with colours running from blue (lowest)
    to red (highest) along z."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    z = points[:, 2]
    f = (z - z.min()) / max(float(np.ptp(z)), 1e-9) if len(z) else z
    colours = np.column_stack([255 * f, 255 * (1 - np.abs(2 * f - 1)), 255 * (1 - f)])
    rows = np.empty(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                        ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    rows["x"], rows["y"], rows["z"] = points.T
    rows["red"], rows["green"], rows["blue"] = np.rint(colours).astype(np.uint8).T
    header = ("ply\nformat binary_little_endian 1.0\ncomment sdvl map: occupied voxel centres\n"
              f"element vertex {len(points)}\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\n"
              "property uchar blue\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(rows.tobytes())
