"""Feature alignment (thesis 6.7.2): project map points into the new frame, and in each grid cell
match the most-seen point first until one is found, up to a cap on matches."""

from __future__ import annotations

import numba
import numpy as np

from calib.camera import project_point
from vo.matcher import match_direct
from vo.se3 import inv_se3, transform


@numba.njit(cache=True, nogil=True)
def project_visible(params, T_c_w, pos_w, idx, width, height, margin):
    """Level-0 pixels (N, 2) of points idx and a mask of those inside the image."""
    n = idx.shape[0]
    px = np.empty((n, 2))
    vis = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        p = idx[k]
        X, Y, Z = transform(T_c_w, pos_w[p, 0], pos_w[p, 1], pos_w[p, 2])
        if Z <= 1e-6:
            continue
        u, v = project_point(params, X, Y, Z)
        if np.isnan(u):
            continue
        px[k, 0] = u
        px[k, 1] = v
        vis[k] = u >= margin and v >= margin and u < width - margin and v < height - margin
    return px, vis


@numba.njit(cache=True, nogil=True)
def match_in_cells(params, order, px, cell, T_c_w, host, hu, hv, hlevel, f, rho, kf_pyr,
                   kf_T_c_w, pyr_off, pyr_w, pyr_h, cur_flat, max_level, max_matches,
                   iterations):
    """Try points in `order` (grouped by cell, best first); the first success closes its cell.

    Returns (matched positions into order's arrays, u, v, level, attempted mask).
    """
    n = order.shape[0]
    done = np.zeros(cell.max() + 1 if n > 0 else 1, dtype=np.bool_)
    out_k = np.empty(n, dtype=np.int64)
    out_uv = np.empty((n, 2))
    out_level = np.empty(n, dtype=np.int64)
    attempted = np.zeros(n, dtype=np.bool_)
    m = 0
    for k in order:
        if m >= max_matches:
            break
        if done[cell[k]]:
            continue
        attempted[k] = True
        s = host[k]
        T_cur_ref = T_c_w @ inv_se3(kf_T_c_w[s])
        u, v, level, ok = match_direct(params, kf_pyr[s], pyr_off, pyr_w, pyr_h, hu[k], hv[k],
                                       hlevel[k], f[k], 1.0 / rho[k], T_cur_ref, cur_flat,
                                       pyr_off, pyr_w, pyr_h, px[k, 0], px[k, 1], max_level,
                                       iterations)
        if ok:
            done[cell[k]] = True
            out_k[m] = k
            out_uv[m, 0] = u
            out_uv[m, 1] = v
            out_level[m] = level
            m += 1
    return out_k[:m], out_uv[:m], out_level[:m], attempted


class Reprojector:
    """Per-frame projection and grid-limited matching of map points."""

    def __init__(self, width: int, height: int, cell: int, seed: int):
        self.width, self.height, self.cell = width, height, cell
        self.cols = (width + cell - 1) // cell
        n_cells = self.cols * ((height + cell - 1) // cell)
        # a fixed random cell order, so the match cap does not favour the image top
        self.cell_rank = np.random.default_rng(seed).permutation(n_cells)

    def cell_of(self, px: np.ndarray) -> np.ndarray:
        """Grid cell index of level-0 pixels."""
        return (px[:, 1] // self.cell).astype(np.int64) * self.cols + (
            px[:, 0] // self.cell).astype(np.int64)

    def run(self, params, frame, pts, idx: np.ndarray, kf_pyr, kf_T_c_w, max_level: int,
            max_matches: int, iterations: int):
        """Match points `idx` of store `pts` in `frame` (pose T_c_w set to its prior).

        Returns (point ids, uv (M, 2), levels, n_visible, n_attempts, attempted point ids).
        """
        px, vis = project_visible(params, frame.T_c_w, pts.pos_w, idx, self.width, self.height,
                                  8.0)
        idx, px = idx[vis], px[vis]
        if len(idx) == 0:
            empty = np.zeros(0, dtype=np.int64)
            return empty, np.zeros((0, 2)), empty, 0, 0, empty
        cell = self.cell_of(px)
        order = np.lexsort((-pts.n_found[idx], self.cell_rank[cell]))
        pyr = frame.pyr
        k, uv, level, attempted = match_in_cells(
            params, order, px, cell, frame.T_c_w, pts.host[idx], pts.u[idx], pts.v[idx],
            pts.level[idx], pts.f[idx], pts.rho[idx], kf_pyr, kf_T_c_w, pyr.offsets,
            pyr.widths, pyr.heights, pyr.flat, max_level, max_matches, iterations)
        return idx[k], uv, level, len(idx), int(attempted.sum()), idx[attempted]
