"""The occupancy map: the numba kernel against a slow obvious reference and against the OctoMap
library itself, growth, range limit, the files it writes, and the synthetic room's precision
and recall (acceptance: >= 90% at 5 cm voxels)."""

from __future__ import annotations

import contextlib
import itertools
import json
import math

import numpy as np
import octomap
import pytest

from daemon.map_files import write_map
from sdvl.cli import main
from vo.occupancy import OccupancyMap, OccupancySettings, logit

VOXEL = 0.1


def segment_voxels(a, b, voxel):
    """Every voxel the segment a-b passes through (slab test on each voxel of its box)."""
    lo = np.floor(np.minimum(a, b) / voxel).astype(int)
    hi = np.floor(np.maximum(a, b) / voxel).astype(int)
    out = set()
    d = b - a
    for key in itertools.product(*(range(lo[k], hi[k] + 1) for k in range(3))):
        t0, t1 = 0.0, 1.0
        for k in range(3):
            box0, box1 = key[k] * voxel, (key[k] + 1) * voxel
            if abs(d[k]) < 1e-15:
                if not box0 <= a[k] < box1:
                    t0, t1 = 1.0, 0.0
                continue
            s0, s1 = sorted(((box0 - a[k]) / d[k], (box1 - a[k]) / d[k]))
            t0, t1 = max(t0, s0), min(t1, s1)
        if t0 <= t1:
            out.add(key)
    return out


def reference_insert(logodds: dict, points, origin, s: OccupancySettings):
    """One scan the obvious way: end voxels get a hit, the rest of every ray a miss, each
    voxel once, hits first."""
    def key(p):
        return tuple(np.floor(p / s.voxel_m).astype(int))

    hits, free = set(), set()
    for p in points:
        length = np.linalg.norm(p - origin)
        end = p if not s.max_range_m or length <= s.max_range_m else \
            origin + (p - origin) * s.max_range_m / length
        voxels = segment_voxels(origin, end, s.voxel_m)
        if not s.max_range_m or length <= s.max_range_m:
            hits.add(key(p))
            voxels.discard(key(p))
        free |= voxels
    lo, hi = logit(s.clamp_min), logit(s.clamp_max)
    for v, step in [(v, logit(s.prob_hit)) for v in hits] + \
            [(v, logit(s.prob_miss)) for v in free - hits]:
        logodds[v] = min(max(logodds.get(v, 0.0) + step, lo), hi)


def as_dict(occupancy: OccupancyMap) -> dict:
    keys, values = occupancy.voxels()
    return {tuple(k): float(v) for k, v in zip(keys.tolist(), values, strict=True)}


def scans(seed, n_scans=3, n_points=40):
    rng = np.random.default_rng(seed)
    for _ in range(n_scans):
        origin = rng.uniform(-0.3, 0.3, 3)
        yield origin + rng.normal(0, 1, (n_points, 3)) * [1.0, 1.0, 0.4] + (0, 0, 1.5), origin


@pytest.mark.parametrize("max_range", [0.0, 1.2])
def test_kernel_matches_the_reference(max_range):
    settings = OccupancySettings(voxel_m=VOXEL, max_range_m=max_range)
    fast, slow = OccupancyMap(settings, capacity=1), {}  # capacity 1: it must grow
    for points, origin in scans(5):
        fast.insert(points, origin)
        reference_insert(slow, points, origin, settings)
    got = as_dict(fast)
    assert got.keys() == slow.keys()
    np.testing.assert_allclose([got[k] for k in slow], list(slow.values()), atol=1e-5)
    assert fast.n_blocks > 1 and len(fast.occupied()) > 0


def test_agrees_with_octomaps_own_insert_point_cloud():
    """OctoMap's insertPointCloud (the C++ library) on the same scans: every voxel it knows
    has our log-odds (rays that pass exactly through voxel corners may differ)."""
    settings = OccupancySettings(voxel_m=VOXEL)
    ours = OccupancyMap(settings)
    tree = octomap.OcTree(VOXEL)
    for points, origin in scans(6, n_scans=4, n_points=300):
        ours.insert(points, origin)
        tree.insertPointCloud(points, origin)
    keys, values = ours.voxels()
    theirs = np.full(len(keys), np.nan)
    for i, centre in enumerate(ours.centres(keys)):
        with contextlib.suppress(octomap.NullPointerException):  # a voxel it does not have
            theirs[i] = tree.search(centre).getLogOdds()
    assert np.isclose(theirs, values, atol=1e-4).mean() > 0.995
    occupied, free = tree_voxels(tree, VOXEL)  # and nothing more: its leaves are ours
    known = len(occupied | free)
    assert known == pytest.approx(len(keys), rel=0.005)
    assert len(occupied ^ {tuple(k) for k in keys[values > 0].tolist()}) < 0.005 * known


def test_rays_beyond_max_range_only_clear_space():
    occupancy = OccupancyMap(OccupancySettings(voxel_m=VOXEL, max_range_m=1.0))
    occupancy.insert(np.array([[0.05, 0.05, 3.05]]), np.array([0.05, 0.05, 0.05]))
    keys, values = occupancy.voxels()
    assert len(occupancy.occupied()) == 0 and (values < 0).all()
    assert keys[:, 2].max() == 10 and keys[:, 2].min() == 0  # 0 .. 1.05 m along z


def octree_voxels(path, voxel):
    """Occupied and free voxel keys of an OctoMap file, leaves larger than a voxel expanded."""
    if path.suffix == ".bt":
        tree = octomap.OcTree(voxel)
        assert tree.readBinary(str(path))
    else:
        tree = octomap.OcTree.read(str(path))
    return tree_voxels(tree, voxel)


def tree_voxels(tree, voxel):
    """Occupied and free voxel keys of an OcTree, leaves larger than a voxel expanded."""
    found = {True: set(), False: set()}
    for leaf in tree.begin_leafs():
        n = max(1, round(leaf.getSize() / voxel))
        corner = np.floor((np.asarray(leaf.getCoordinate()) - leaf.getSize() / 2) / voxel + 0.5)
        for offset in itertools.product(range(n), repeat=3):
            found[leaf.getValue() > 0].add(tuple(int(c) for c in corner + offset))
    return found[True], found[False]


@pytest.fixture(scope="module")
def small_map():
    occupancy = OccupancyMap(OccupancySettings(voxel_m=VOXEL))
    for points, origin in scans(7, n_points=200):
        occupancy.insert(points, origin)
    return occupancy


@pytest.mark.parametrize("suffix", [".bt", ".ot"])
def test_octomap_files_hold_the_map(tmp_path, small_map, suffix):
    path = tmp_path / f"map{suffix}"
    write_map(small_map, path)
    occupied, free = octree_voxels(path, VOXEL)
    keys, values = small_map.voxels()
    assert occupied == {tuple(k) for k in keys[values > 0].tolist()}
    assert free == {tuple(k) for k in keys[values <= 0].tolist()}
    if suffix == ".ot":  # the full tree keeps each voxel's log-odds
        tree = octomap.OcTree.read(str(path))
        got = [tree.search(c).getLogOdds() for c in small_map.centres(keys[:50])]
        np.testing.assert_allclose(got, values[:50], atol=1e-5)


def test_ply_holds_the_occupied_voxel_centres(tmp_path, small_map):
    path = tmp_path / "map.ply"
    write_map(small_map, path)
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    n = len(small_map.occupied())
    assert f"element vertex {n}".encode() in header and len(body) == n * 15
    rows = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    np.testing.assert_allclose(rows["xyz"], small_map.centres(small_map.occupied()), atol=1e-6)


def test_room_map_precision_and_recall(tmp_path, capsys):
    """Acceptance: the synthetic room mapped from ground-truth poses with the preset's D435
    model, 5 cm voxels: >= 90% of the occupied voxels on a surface of the room, >= 90% of the
    surfaces the camera saw occupied."""
    out = tmp_path / "room.bt"
    assert main(["map", "room-handheld", "--out", str(out), "--poses", "groundtruth",
                 "--score", "--max-frames", "130", "--every", "8", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    score = report["score"]
    assert score["precision"] >= 0.9 and score["recall"] >= 0.9, score
    assert report["voxel_m"] == 0.05 and out.stat().st_size > 1000
    assert math.isfinite(report["fuse_ms_median"])


@pytest.mark.parametrize("argv, message", [
    (["map", "room-handheld", "--out", "x.pcd"], "--out must end in"),
    (["map", "room-handheld", "--out", "x.bt", "--poses", "sdvl"], "no metric scale"),
    (["map", "room-handheld", "--out", "x.bt", "--voxel", "0"], "--voxel"),
])
def test_map_argument_errors_are_one_line(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


def test_map_of_a_sequence_without_depth_is_an_error(data_dir, capsys, tmp_path):
    assert main(["map", str(data_dir / "vamr_ex01_checkerboard736"), "--out",
                 str(tmp_path / "m.bt")]) == 2
    assert "no depth maps" in capsys.readouterr().err
