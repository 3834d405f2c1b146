"""Feature alignment (thesis 6.7.2): project map points into the new frame, and in each grid cell
match the most-seen point first until one is found, up to a cap on matches."""

from __future__ import annotations

import numba
import numpy as np

from calib.camera import CameraModel, project_point, unproject_pixel
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.map import Map
from vo.matcher import match_direct, match_epipolar
from vo.orb import OrbQuery, query
from vo.se3 import compose, inv_se3, transform


@numba.njit(cache=True, nogil=True)
def project_visible(params, T_c_w, pos_w, idx, width, height, margin, max_r2):
    """Level-0 pixels (N, 2) of points idx and a mask of those inside the image (and inside
    the field of view, max_r2 on the normalised plane, where distortion models are valid)."""
    n = idx.shape[0]
    px = np.empty((n, 2))
    vis = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        p = idx[k]
        X, Y, Z = transform(T_c_w, pos_w[p, 0], pos_w[p, 1], pos_w[p, 2])
        r2 = (X * X + Y * Y) / (Z * Z) if Z > 1e-6 else np.inf
        if r2 > max_r2:
            continue
        u, v = project_point(params, X, Y, Z)
        if np.isnan(u):
            continue
        px[k, 0] = u
        px[k, 1] = v
        vis[k] = u >= margin and v >= margin and u < width - margin and v < height - margin
    return px, vis


@numba.njit(cache=True, nogil=True)
def closest_views(params, idx, pos_w, hosts, host_only, obs, kf_T_c_w, cur_centre):
    """Per point idx[k], the keyframe observation whose viewing ray is closest to the current
    one: the host's own detection, hosts = (slot, u, v, level) per k, or one of the map's
    observations, obs = (start, order: Observations.by_point; kf, uv, level columns); only the
    host where host_only[k]. Returns slot, level-0 pixel, level, bearing, ray depth."""
    host, hu, hv, hlevel = hosts
    start, order, obs_kf, obs_uv, obs_level = obs
    n = idx.shape[0]
    slot = np.empty(n, dtype=np.int64)
    uv = np.empty((n, 2))
    level = np.empty(n, dtype=np.int64)
    f = np.empty((n, 3))
    depth = np.empty(n)
    for k in range(n):
        p = idx[k]
        P = pos_w[p]
        rc = P - cur_centre
        rc /= max(np.sqrt(rc @ rc), 1e-12)
        best = -2.0
        n_obs = 0 if host_only[k] else start[p + 1] - start[p]
        for j in range(-1, n_obs):
            if j < 0:
                s, u, v, lv = host[k], hu[k], hv[k], hlevel[k]
            else:
                o = order[start[p] + j]
                s, u, v, lv = obs_kf[o], obs_uv[o, 0], obs_uv[o, 1], obs_level[o]
            T = kf_T_c_w[s]
            X0, X1, X2 = transform(T, P[0], P[1], P[2])
            # ray from the keyframe centre to P, in the world
            r0 = X0 * T[0, 0] + X1 * T[1, 0] + X2 * T[2, 0]
            r1 = X0 * T[0, 1] + X1 * T[1, 1] + X2 * T[2, 1]
            r2 = X0 * T[0, 2] + X1 * T[1, 2] + X2 * T[2, 2]
            c = (r0 * rc[0] + r1 * rc[1] + r2 * rc[2]) / max(
                np.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-12)
            if c > best:
                best = c
                slot[k], uv[k, 0], uv[k, 1], level[k] = s, u, v, lv
                depth[k] = np.sqrt(X0 * X0 + X1 * X1 + X2 * X2)
        f[k, 0], f[k, 1], f[k, 2] = unproject_pixel(params, uv[k, 0], uv[k, 1])
    return slot, uv, level, f, depth


@numba.njit(cache=True, nogil=True)
def match_in_cells(params, T_c_w, cands, keyframes, layout, cur_flat, corners, search, options,
                   state, orb):
    """Try the candidate points in their `order` (grouped by cell, best first); the first
    success closes its cell.

    `cands` = (order, px, cell, slot, ref_uv, ref_level, f, depth, rho, sigma, uncertain):
    per point its predicted level-0 pixel and grid cell, the reference observation to match
    from (keyframe slot, level-0 pixel, level, bearing, ray depth), inverse depth +- sigma,
    and whether its depth is uncertain. `keyframes` = (pyramids, T_c_w) of the map's slots,
    `layout` the pyramids' (offsets, widths, heights), `corners` the frame's FAST corners
    (vo.frame.Corners.tables), `search` the epipolar search (min_level, max_level, margin_px,
    threshold, iterations: vo.matcher.match_epipolar), `options` = (direct_max_level,
    max_matches, fallback).

    Uncertain points are searched along their epipolar segment (rho +- 2 sigma); the others
    are aligned directly at their predicted position (with ORB, orb[0] >= 0, searched along a
    short segment around it: descriptors need corners), and with `fallback` searched so when
    that fails.

    `state` = (done per cell, tried per point, lookahead) carries over between passes: a
    point whose descriptors are pending (vo.orb) is retried in the next pass, and up to
    `lookahead` later points of its cell are looked at meanwhile (their descriptors
    collected, results held back).

    Returns (matched positions into the candidate arrays, u, v, level) of this pass.
    """
    order, px, cell, host, huv, hlevel, f, depth, rho, sigma, uncertain = cands
    kf_pyr, kf_T_c_w = keyframes
    min_level, search_max_level, margin, threshold, iterations = search
    max_level, max_matches, fallback = options
    done, tried, lookahead = state
    n = order.shape[0]
    waiting = np.zeros(done.shape[0], dtype=np.int64)
    out_k = np.empty(n, dtype=np.int64)
    out_uv = np.empty((n, 2))
    out_level = np.empty(n, dtype=np.int64)
    use_orb = orb[0] >= 0
    # T_cur_ref per keyframe slot, computed on its first use
    T_slot = np.empty((kf_T_c_w.shape[0], 4, 4))
    have = np.zeros(kf_T_c_w.shape[0], dtype=np.bool_)
    m = 0
    for k in order:
        if m >= max_matches:
            break
        c = cell[k]
        if done[c] or tried[k] or waiting[c] >= lookahead:
            continue
        s = host[k]
        if not have[s]:
            T_slot[s] = compose(T_c_w, inv_se3(kf_T_c_w[s]))
            have[s] = True
        T_cur_ref = T_slot[s]
        ref_obs = (huv[k, 0], huv[k, 1], hlevel[k], f[k])
        pending = orb[8][0]
        u = v = 0.0
        level = 0
        r, r_sigma, r_margin = rho[k], sigma[k], margin
        ok = False
        if not uncertain[k]:
            if not use_orb:
                u, v, level, ok = match_direct(params, layout, kf_pyr[s], ref_obs, depth[k],
                                               T_cur_ref, cur_flat, px[k, 0], px[k, 1],
                                               max_level, iterations)
            # ORB, or prediction too far off for direct alignment: search FAST corners along
            # the point's (short) epipolar segment as the thesis matcher does
            r = 1.0 / depth[k]
            r_sigma = r * max(sigma[k] / rho[k], 0.05)
            r_margin = 2.0 * margin
        if not ok and (uncertain[k] or use_orb or (fallback and corners[0].shape[0] > 0)):
            u, v, level, ok = match_epipolar(
                params, layout, kf_pyr[s], ref_obs, r, r_sigma, T_cur_ref, cur_flat, corners,
                (min_level, search_max_level, r_margin, threshold, iterations),
                query(orb, k))
        if orb[8][0] > pending or waiting[c] > 0:
            waiting[c] += 1
            continue
        tried[k] = True
        if ok:
            done[c] = True
            out_k[m] = k
            out_uv[m, 0] = u
            out_uv[m, 1] = v
            out_level[m] = level
            m += 1
    return out_k[:m], out_uv[:m], out_level[:m]


class Reprojector:
    """Per-frame projection and grid-limited matching of map points."""

    def __init__(self, camera: CameraModel, config: TrackerConfig):
        width, height = camera.width, camera.height
        cell = config.grid_cell
        self.camera, self.config = camera, config
        self.width, self.height, self.cell = width, height, cell
        corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]],
                           dtype=np.float64)
        f = camera.unproject(corners)
        self.max_r2 = 1.2 * float(np.max((f[:, 0] ** 2 + f[:, 1] ** 2) / f[:, 2] ** 2))
        self.cols = (width + cell - 1) // cell
        self.n_cells = self.cols * ((height + cell - 1) // cell)
        # a fixed random cell order, so the match cap does not favour the image top
        self.cell_rank = np.random.default_rng(config.seed).permutation(self.n_cells)
        cfg = config
        self.options = (cfg.pyramid_levels - 1, cfg.max_matches, cfg.track_search_fallback)

    def cell_of(self, px: np.ndarray) -> np.ndarray:
        """Grid cell index of level-0 pixels."""
        return (px[:, 1] // self.cell).astype(np.int64) * self.cols + (
            px[:, 0] // self.cell).astype(np.int64)

    def run(self, frame: Frame, map_: Map, idx: np.ndarray, uncertain: np.ndarray):
        """Match points `idx` of the map in `frame` (pose T_c_w set to its prior); those
        flagged `uncertain` are searched along their epipolar segments.

        Returns (point ids, uv (M, 2), levels, n_visible, n_attempts, attempted point ids);
        n_visible counts the grid cells the usable points project into (one match per cell:
        what tracking can match at most), less points that have kept failing
        (kf_cell_max_unmatched).
        """
        cands = self._candidates(frame, map_, idx, uncertain)
        if cands is None:
            empty = np.zeros(0, dtype=np.int64)
            return empty, np.zeros((0, 2)), empty, 0, 0, empty
        idx = cands[-1]
        cfg = self.config
        use_orb = cfg.matcher == "orb"
        corners = _NO_CORNERS
        c = None
        if cands[-2].any() or cfg.track_search_fallback or use_orb:
            c = frame.corners(cfg.fast_threshold, cfg.track_corner_level, cfg.match_max_level)
            corners = c.tables
        pts = map_.points
        if use_orb:
            orb = OrbQuery(cfg.orb_max_distance, idx, pts.desc, pts.desc_state,
                           cfg.pyramid_levels, frame.orb, c, map_.describe_points)
        else:
            orb = OrbQuery.patches(len(idx), cfg.pyramid_levels)
        tried = np.zeros(len(idx), dtype=np.bool_)
        k, uv, level = self._match_passes(frame, map_, cands[:-1], corners, orb, tried)
        live = pts.n_unmatched[idx] < cfg.kf_cell_max_unmatched
        n_cells = len(np.unique(cands[2][live]))
        return idx[k], uv, level, n_cells, int(tried.sum()), idx[tried]

    def _candidates(self, frame: Frame, map_: Map, idx: np.ndarray, uncertain: np.ndarray):
        """The candidate table of match_in_cells for the points idx visible in frame, with
        the point ids last; None when none is visible."""
        pts, obs = map_.points, map_.obs
        px, vis = project_visible(self.camera.params, frame.T_c_w, pts.pos_w, idx, self.width,
                                  self.height, 8.0, self.max_r2)
        idx, px, uncertain = idx[vis], px[vis], uncertain[vis]
        if len(idx) == 0:
            return None
        cell = self.cell_of(px)
        order = np.lexsort((-pts.n_found[idx], self.cell_rank[cell]))
        start, obs_order = obs.by_point(pts.capacity)
        # ORB descriptors are kept for the host's view: match against the host then
        slot, ref_uv, ref_level, f, depth = closest_views(
            self.camera.params, idx, pts.pos_w,
            (pts.host[idx], pts.u[idx], pts.v[idx], pts.level[idx]),
            uncertain | (self.config.matcher == "orb"),
            (start, obs_order, obs.kf, obs.uv, obs.level), map_.kf_T_c_w, frame.position)
        return (order, px, cell, slot, ref_uv, ref_level, f, depth, pts.rho[idx],
                pts.sigma[idx], uncertain, idx)

    def _match_passes(self, frame: Frame, map_: Map, cands: tuple, corners: tuple,
                      orb: OrbQuery, tried: np.ndarray):
        """Rounds of one match per grid cell, another while the points are crowded into
        fewer than crowded_min_matches cells (two or more per cell) and fewer matched:
        positions into the candidates, u, v, level; `tried` marks the points tried."""
        found: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        least = self.config.crowded_min_matches
        cells = len(np.unique(cands[2])) if least > 0 else 0
        crowded = 0 < cells < least and len(cands[2]) >= 2 * cells
        n_found = 0
        while True:
            before = n_found
            n_found = self._round(frame, map_, cands, corners, orb, tried, found, n_found)
            if not crowded or n_found == before or n_found >= least or tried.all():
                break
        return tuple(np.concatenate([a[i] for a in found]) for i in range(3))

    def _round(self, frame: Frame, map_: Map, cands: tuple, corners: tuple, orb: OrbQuery,
               tried: np.ndarray, found: list, n_found: int) -> int:
        """One match per cell among the points not tried yet: match_in_cells until no ORB
        descriptor is pending (one pass with patches), appending to `found`; the count
        matched so far."""
        cfg = self.config
        search = (cfg.track_corner_level, cfg.match_max_level, cfg.epipolar_margin_px,
                  cfg.zmssd_threshold, cfg.align2d_iterations)
        max_level, max_matches, fallback = self.options
        done = np.zeros(self.n_cells, dtype=np.bool_)
        lookahead = 1
        while True:
            k, uv, level = match_in_cells(
                self.camera.params, frame.T_c_w, cands, (map_.kf_pyr, map_.kf_T_c_w),
                frame.pyr.layout, frame.pyr.flat, corners, search,
                (max_level, max_matches - n_found, fallback), (done, tried, lookahead),
                orb.tables)
            found.append((k, uv, level))
            n_found += len(k)
            if not orb.fill():
                return n_found
            lookahead *= 2


# the corner table of a frame whose corners no search needs
_NO_CORNERS = (np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0),
               np.zeros((1, 1), dtype=np.int64))
