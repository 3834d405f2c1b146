"""How well an occupancy map of a synthetic flight matches the world it was made in.

Precision: the fraction of the map's occupied voxels that a surface of the scene passes
through (touching a voxel's boundary counts). Recall: the fraction of the surfaces the depth
camera saw (noise-free depth within the sensor's range, at the fused frames) whose voxel is
occupied in the map.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim.synth.scene import QuadList

_BIAS = 1 << 20
_EPS = 1e-6  # voxels: a point this close to a voxel face touches the voxel beyond it too


def pack(keys: np.ndarray) -> np.ndarray:
    """Integer voxel coordinates (N, 3) as one int64 each (for set operations)."""
    k = keys.astype(np.int64) + _BIAS
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def touching(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """(N, 8) packed keys of the voxels each point touches (the same key repeated when the
    point is inside one voxel; two, four or eight different on faces, edges, corners)."""
    q = points / voxel_m
    lo, hi = np.floor(q - _EPS).astype(np.int64), np.floor(q + _EPS).astype(np.int64)
    out = np.empty((len(points), 8), np.int64)
    for n in range(8):
        pick = [(n >> axis) & 1 for axis in range(3)]
        keys = np.column_stack([hi[:, a] if pick[a] else lo[:, a] for a in range(3)])
        out[:, n] = pack(keys)
    return out


def surface_voxels(quads: QuadList, voxel_m: float, lo: np.ndarray,
                   hi: np.ndarray) -> np.ndarray:
    """Packed keys of the voxels the quads pass through inside the box [lo, hi] (m): each
    quad sampled at a quarter voxel, clipped to the box."""
    spacing = voxel_m / 4
    keys = []
    corners = np.array(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij")).reshape(3, -1).T
    for g in quads.geometry:
        o, u, v, eu, ev = g[0:3], g[3:6], g[6:9], g[9], g[10]
        a, b = (corners - o) @ u, (corners - o) @ v  # the box in quad coordinates
        a0, a1 = max(a.min(), 0.0), min(a.max(), eu)
        b0, b1 = max(b.min(), 0.0), min(b.max(), ev)
        if a0 > a1 or b0 > b1:
            continue
        sa = np.linspace(a0, a1, max(2, int(np.ceil((a1 - a0) / spacing)) + 1))
        sb = np.linspace(b0, b1, max(2, int(np.ceil((b1 - b0) / spacing)) + 1))
        aa, bb = np.meshgrid(sa, sb, indexing="ij")
        pts = o + aa.reshape(-1, 1) * u + bb.reshape(-1, 1) * v
        inside = np.all((pts >= lo) & (pts <= hi), axis=1)
        keys.append(np.unique(touching(pts[inside], voxel_m)))
    return np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)


@dataclass
class MapScore:
    """Precision and recall of occupied voxels (fractions) and the counts behind them."""

    precision: float
    recall: float
    occupied: int
    occupied_on_surface: int
    seen_surface: int
    seen_recalled: int

    def to_dict(self) -> dict:
        """Plain values for JSON."""
        return asdict(self)


def seen_voxels(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """The seen-surface voxels of surface points (N, 3, world): (M, 8) packed keys, one row
    per voxel a point lies in, with the voxels it touches (see `touching`)."""
    seen = touching(points, voxel_m)
    _, first = np.unique(seen[:, 0], return_index=True)
    return seen[first]


def score_map(occupied: np.ndarray, quads: QuadList, seen: np.ndarray,
              voxel_m: float) -> MapScore:
    """Score occupied voxels (integer coordinates (M, 3)) against the scene's quads and the
    surfaces the camera saw (`seen_voxels` rows; several frames' may be stacked)."""
    _, first = np.unique(seen[:, 0], return_index=True)
    seen = seen[first]
    occ = np.unique(pack(occupied))
    margin = 2 * voxel_m
    corners = np.vstack([(occupied + 0.5) * voxel_m, unpack(seen[:, 0]) * voxel_m])
    truth = surface_voxels(quads, voxel_m, corners.min(axis=0) - margin,
                           corners.max(axis=0) + margin)
    on_surface = int(np.isin(occ, truth).sum())
    recalled = int(np.isin(seen, occ).any(axis=1).sum())
    return MapScore(on_surface / max(len(occ), 1), recalled / max(len(seen), 1), len(occ),
                    on_surface, len(seen), recalled)


def unpack(keys: np.ndarray) -> np.ndarray:
    """Integer voxel coordinates (N, 3) of packed keys (the inverse of `pack`)."""
    mask = (1 << 21) - 1
    return np.column_stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask]) - _BIAS
