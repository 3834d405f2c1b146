"""A 3D occupancy map fused from depth maps along metric camera poses, as OctoMap defines one
(A. Hornung et al., "OctoMap: an efficient probabilistic 3D mapping framework based on
octrees", Autonomous Robots 34, 2013): each voxel holds the log-odds of being occupied; a
measurement's end point adds log(p_hit / (1 - p_hit)) to its voxel, every voxel the ray
crosses before it adds log(p_miss / (1 - p_miss)); values are clamped so the map stays
updatable; within one scan each voxel is updated once, and a voxel some ray ends in is not
also made freer by another ray (OctoMap's insertPointCloud). Defaults are OctoMap's.

Storage is sparse: blocks of 16^3 voxels, created where rays go, found through an
open-addressing hash table (linear probing, at most half full);
ray traversal is the voxel walk of J. Amanatides and A. Woo, "A fast voxel traversal algorithm
for ray tracing" (Eurographics 1987), in a numba kernel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

BLOCK = 16  # voxels per block side
_BIAS = 1 << 20  # block coordinates are stored as 21-bit fields, +-2^20 blocks
UNSEEN = -1  # stamp of a voxel no scan has updated
EMPTY = -1  # key of a free hash table row (block keys are >= 0)


def logit(p: float) -> float:
    """log(p / (1 - p))."""
    return math.log(p / (1.0 - p))


@dataclass(frozen=True)
class OccupancySettings:
    """Voxel size (m) and the sensor model; probabilities as OctoMap's defaults."""

    voxel_m: float = 0.05  # fine enough for a drone's clearance of tens of centimetres
    prob_hit: float = 0.7  # P(occupied) of the voxel a measurement ends in
    prob_miss: float = 0.4  # P(occupied) of a voxel a measurement's ray crosses
    clamp_min: float = 0.1192  # a voxel never gets surer than this that it is free
    clamp_max: float = 0.971  # ... or occupied, so the map can still change
    max_range_m: float = 0.0  # rays longer than this only free space up to it (0: no limit)


class OccupancyMap:
    """Sparse log-odds voxel map; `insert` fuses one scan (points seen from one origin)."""

    def __init__(self, settings: OccupancySettings | None = None, capacity: int = 64):
        self.settings = settings or OccupancySettings()
        self.table = np.full((2 * capacity, 2), EMPTY, np.int64)  # (block key, index) rows
        self.logodds = np.zeros((capacity, BLOCK, BLOCK, BLOCK), np.float32)
        self.stamps = np.full((capacity, BLOCK, BLOCK, BLOCK), UNSEEN, np.int32)
        self.origins = np.zeros((capacity, 3), np.int64)  # each block's first voxel
        self._count = np.zeros(1, np.int64)  # blocks in use (an array: kernels update it)
        self.scans = 0

    def insert(self, points: np.ndarray, origin: np.ndarray) -> None:
        """Fuse the measured end points (N, 3, world frame, m) of rays from `origin` (3,)."""
        s = self.settings
        params = np.array([s.voxel_m, logit(s.prob_hit), logit(s.prob_miss),
                           logit(s.clamp_min), logit(s.clamp_max), s.max_range_m])
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        origin = np.ascontiguousarray(origin, dtype=np.float64)
        ends, hits = _ray_ends(points, origin, params[0], params[5])
        for kernel, values in ((_hits, points[hits]), (_rays, ends)):
            done = 0
            while done < len(values):  # a kernel stops when the blocks may run out
                done = kernel(values, origin, params, self.scans, hits, self.table,
                              self.logodds, self.stamps, self.origins, self._count, done)
                if done < len(values):
                    self._grow()
        self.scans += 1

    @property
    def n_blocks(self) -> int:
        """Blocks in use."""
        return int(self._count[0])

    def _grow(self) -> None:
        """Twice the room for blocks (and a hash table twice as large)."""
        cap = len(self.logodds)
        self.logodds = np.concatenate([self.logodds, np.zeros_like(self.logodds)])
        self.stamps = np.concatenate([self.stamps, np.full_like(self.stamps, UNSEEN)])
        self.origins = np.concatenate([self.origins, np.zeros((cap, 3), np.int64)])
        self.table = _rehash(self.table, 4 * cap)

    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Every voxel a scan has updated: integer coordinates (M, 3) (voxel (i, j, k) spans
        [i, i + 1) x voxel_m along x, ...) and their log-odds (M,)."""
        n = self.n_blocks
        seen = self.stamps[:n] != UNSEEN
        b, i, j, k = np.nonzero(seen)
        keys = self.origins[b] + np.column_stack([i, j, k])
        return keys, self.logodds[:n][seen]

    def occupied(self) -> np.ndarray:
        """Integer coordinates (M, 3) of the voxels more likely occupied than not."""
        keys, logodds = self.voxels()
        return keys[logodds > 0]

    def centres(self, keys: np.ndarray) -> np.ndarray:
        """World coordinates (M, 3) of voxel centres."""
        return (keys + 0.5) * self.settings.voxel_m

    def memory_bytes(self) -> int:
        """Bytes the voxel blocks hold (allocated, used or not)."""
        return self.logodds.nbytes + self.stamps.nbytes + self.origins.nbytes


@numba.njit(cache=True, nogil=True, inline="always")
def _block_key(bx, by, bz):
    return ((bx + _BIAS) << 42) | ((by + _BIAS) << 21) | (bz + _BIAS)


@numba.njit(cache=True, nogil=True, inline="always")
def _slot(table, key):
    """The row of `key` in the hash table, or the empty row where it belongs."""
    mask = table.shape[0] - 1
    i = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)) & mask
    while table[i, 0] != key and table[i, 0] != EMPTY:
        i = (i + 1) & mask
    return i


@numba.njit(cache=True, nogil=True)
def _rehash(table, size):
    """A hash table of `size` rows (a power of two) holding the same entries."""
    out = np.full((size, 2), EMPTY, np.int64)
    for row in range(table.shape[0]):
        if table[row, 0] != EMPTY:
            i = _slot(out, table[row, 0])
            out[i, 0], out[i, 1] = table[row, 0], table[row, 1]
    return out


@numba.njit(cache=True, nogil=True)
def _block(bx, by, bz, table, origins, count):
    """Index of block (bx, by, bz), created if new (the caller made sure there is room)."""
    key = _block_key(bx, by, bz)
    i = _slot(table, key)
    if table[i, 0] == key:
        return table[i, 1]
    b = count[0]
    table[i, 0], table[i, 1] = key, b
    origins[b, 0], origins[b, 1], origins[b, 2] = bx << 4, by << 4, bz << 4
    count[0] = b + 1
    return b


@numba.njit(cache=True, nogil=True)
def _ray_ends(points, origin, voxel, max_range):
    """Where each ray's free space ends (its point, or `max_range` along it) and whether it
    ends in a measurement (not beyond max_range, not at the origin)."""
    ends = np.empty_like(points)
    hits = np.zeros(points.shape[0], np.bool_)
    for n in range(points.shape[0]):
        d = points[n] - origin
        length = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        hits[n] = length > 0.0 and (max_range <= 0.0 or length <= max_range)
        ends[n] = points[n] if hits[n] or not length > 0.0 else origin + d * (max_range / length)
    return ends, hits


@numba.njit(cache=True, nogil=True)
def _hits(points, origin, p, scan, hits, table, logodds, stamps, origins, count, start):
    """Add p_hit to the voxel of each point from `start` on; returns where it stopped (the
    number of points when done, earlier when the blocks ran out)."""
    voxel, l_hit, cmin, cmax = p[0], p[1], p[3], p[4]
    for n in range(start, points.shape[0]):
        if count[0] == logodds.shape[0]:
            return n
        ix = int(np.floor(points[n, 0] / voxel))
        iy = int(np.floor(points[n, 1] / voxel))
        iz = int(np.floor(points[n, 2] / voxel))
        b = _block(ix >> 4, iy >> 4, iz >> 4, table, origins, count)
        i, j, k = ix & 15, iy & 15, iz & 15
        if stamps[b, i, j, k] < 2 * scan + 1:  # once per scan
            logodds[b, i, j, k] = min(max(logodds[b, i, j, k] + l_hit, cmin), cmax)
            stamps[b, i, j, k] = 2 * scan + 1
    return points.shape[0]


@numba.njit(cache=True, nogil=True)
def _rays(ends, origin, p, scan, hits, table, logodds, stamps, origins, count, start):
    """Walk each ray from the origin to its end from `start` on (Amanatides-Woo) and make
    every voxel freer once this scan, the last one too unless the ray ends in a measurement
    there; returns where it stopped (the number of rays when done, earlier when the blocks
    may run out)."""
    voxel, l_miss, cmin, cmax = p[0], p[2], p[3], p[4]
    stamp = 2 * scan
    cell = np.empty(3, np.int64)
    step = np.zeros(3, np.int64)
    t_max = np.empty(3)
    t_delta = np.empty(3)
    for n in range(start, ends.shape[0]):
        n_steps, n_blocks = 0, 1
        for k in range(3):
            pos, end = origin[k] / voxel, ends[n, k] / voxel
            cell[k] = int(np.floor(pos))
            last = int(np.floor(end))
            n_steps += abs(last - cell[k])
            n_blocks += abs((last >> 4) - (cell[k] >> 4))
            d = end - pos
            step[k], t_max[k], t_delta[k] = 0, np.inf, np.inf
            if d > 0.0:
                step[k], t_max[k], t_delta[k] = 1, (cell[k] + 1.0 - pos) / d, 1.0 / d
            elif d < 0.0:
                step[k], t_max[k], t_delta[k] = -1, (pos - cell[k]) / -d, -1.0 / d
        if count[0] + n_blocks > logodds.shape[0]:
            return n
        block_key, b = np.int64(-1), 0
        for _ in range(n_steps + 1 - int(hits[n])):
            key = _block_key(cell[0] >> 4, cell[1] >> 4, cell[2] >> 4)
            if key != block_key:
                b = _block(cell[0] >> 4, cell[1] >> 4, cell[2] >> 4, table, origins, count)
                block_key = key
            vi, vj, vk = cell[0] & 15, cell[1] & 15, cell[2] & 15
            if stamps[b, vi, vj, vk] < stamp:  # once per scan (the call costs 2x here)
                logodds[b, vi, vj, vk] = min(max(logodds[b, vi, vj, vk] + l_miss, cmin), cmax)
                stamps[b, vi, vj, vk] = stamp
            k = 0 if t_max[0] <= t_max[1] and t_max[0] <= t_max[2] else (
                1 if t_max[1] <= t_max[2] else 2)
            cell[k] += step[k]
            t_max[k] += t_delta[k]
    return ends.shape[0]
