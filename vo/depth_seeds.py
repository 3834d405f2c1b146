"""Inverse depths of new points from a depth map (issue 30, SDVL with depth): a depth camera
measures a point's inverse depth at once (thesis 6.3: points are kept in inverse depth rho
along their bearing, with a Gaussian sigma the depth filter then refines).

The depth map is registered to the image (one depth per image pixel, metres along the optical
axis, 0 or NaN = no measurement). A point at depth z on the unit bearing f is at range z / f_z,
so rho = f_z / z; a disparity sensor's error sigma_z = k z^2 (vo.config depth_noise_per_m2)
gives sigma_rho = f_z sigma_z / z^2 = k f_z, the same at every distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sdvl.errors import InputError
from vo.config import TrackerConfig


@dataclass
class DepthSeeds:
    """New points with a measured depth: level-0 pixels (N, 2), pyramid levels, unit bearings
    (N, 3), inverse depths and their sigmas."""

    px: np.ndarray
    level: np.ndarray
    f: np.ndarray
    rho: np.ndarray
    sigma: np.ndarray

    def __len__(self) -> int:
        return len(self.rho)


def check_depth_map(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """The depth map as float32, or an InputError saying what is wrong with it."""
    depth = np.asarray(depth)
    if depth.shape != (height, width) or not np.issubdtype(depth.dtype, np.floating):
        raise InputError(f"depth map must be float metres of the image's size {width}x{height}, "
                         f"got {depth.dtype} {depth.shape} (register depth to colour first)")
    return depth.astype(np.float32, copy=False)


def corner_depth(depth: np.ndarray, px: np.ndarray, edge_rel: float) -> np.ndarray:
    """Depth (m) at each level-0 pixel px (N, 2): the median of its 3x3 pixel neighbourhood;
    0 where that has holes or spans more than `edge_rel` of it (a depth edge)."""
    h, w = depth.shape
    c = np.clip(np.rint(px[:, 0]).astype(np.int64), 1, w - 2)
    r = np.clip(np.rint(px[:, 1]).astype(np.int64), 1, h - 2)
    patch = np.stack([depth[r + dr, c + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
    patch = np.where(np.isfinite(patch), patch, 0.0)
    z = np.median(patch, axis=0)
    ok = (patch.min(axis=0) > 0) & (patch.max(axis=0) - patch.min(axis=0) <= edge_rel * z)
    return np.where(ok, z, 0.0)


def measured_inverse_depth(depth: np.ndarray, px: np.ndarray, f: np.ndarray,
                           config: TrackerConfig) -> tuple[np.ndarray, np.ndarray]:
    """(rho, sigma) of points at level-0 pixels px with unit bearings f from the depth map
    (see the module docstring); NaN where the map has no trustworthy depth."""
    z = corner_depth(depth, px, config.depth_edge_rel) if len(px) else np.zeros(0)
    ok = (z > 0) & (f[:, 2] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(ok, f[:, 2] / z, np.nan)
    sigma = np.where(ok, config.depth_noise_per_m2 * f[:, 2], np.nan)
    return rho, sigma


def depth_seeds(depth: np.ndarray, px: np.ndarray, level: np.ndarray, f: np.ndarray,
                config: TrackerConfig) -> DepthSeeds:
    """The points among (px, level, f) that have a measured depth."""
    rho, sigma = measured_inverse_depth(depth, px, f, config)
    ok = np.isfinite(rho)
    return DepthSeeds(px[ok], level[ok], f[ok], rho[ok], sigma[ok])
