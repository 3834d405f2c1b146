"""Mapping (thesis 6.6): depth-filter updates of candidate points on every frame, new candidates
on keyframes (one per empty cell, best Shi-Tomasi corner, matched in a covisible keyframe), and
keyframe removal farthest-first."""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np

from calib.camera import project_point, unproject_pixel
from vo.bundle_adjustment import local_ba
from vo.config import TrackerConfig
from vo.depth_filter import linearity_index, update_seed
from vo.depth_seeds import measured_inverse_depth
from vo.frame import Frame
from vo.initialization import best_per_cell
from vo.map import CANDIDATE, CONVERGED, Map
from vo.matcher import MIN_RHO, inverse_depth_sigma, match_epipolar, triangulate_depth
from vo.orb import DESC_BYTES, OrbQuery, describe_levels, query
from vo.se3 import inv_se3, transform

SHI_TOMASI_HALF = 3
# a point lies on a fitted plane within this fraction of its distance
PLANE_FIT_TOLERANCE = 0.02
MIN_PLANE_POINTS = 8


@numba.njit(cache=True, nogil=True)
def shi_tomasi(flat, off, w, h, level, x, y):
    """Minimum eigenvalue of the structure tensor around integer corners (x, y) of their level."""
    n = x.shape[0]
    out = np.zeros(n)
    r = SHI_TOMASI_HALF
    for i in range(n):
        lv = level[i]
        cx, cy, W, Hh = int(x[i]), int(y[i]), w[lv], h[lv]
        if cx < r + 1 or cy < r + 1 or cx >= W - r - 1 or cy >= Hh - r - 1:
            continue
        gxx = gyy = gxy = 0.0
        for yy in range(cy - r, cy + r + 1):
            base = off[lv] + yy * W
            for xx in range(cx - r, cx + r + 1):
                gx = 0.5 * (float(flat[base + xx + 1]) - float(flat[base + xx - 1]))
                gy = 0.5 * (float(flat[base + W + xx]) - float(flat[base - W + xx]))
                gxx += gx * gx
                gyy += gy * gy
                gxy += gx * gy
        out[i] = 0.5 * (gxx + gyy - np.sqrt((gxx - gyy) ** 2 + 4.0 * gxy * gxy))
    return out


@numba.njit(cache=True, nogil=True)
def _measure(params, layout, ref_flat, ref_obs, rho, sigma, T_cur_ref, cur_flat, corners, search,
             px_angle, orb):
    """Epipolar match of one point (arguments as for vo.matcher.match_epipolar) and the
    inverse-depth measurement it gives, its std from an error of `px_angle` (radians, at
    level 0) in the match: (found, x, tau, u_cur, v_cur)."""
    uc, vc, lv, ok = match_epipolar(params, layout, ref_flat, ref_obs, rho, sigma, T_cur_ref,
                                    cur_flat, corners, search, orb)
    if not ok:
        return False, 0.0, 0.0, uc, vc
    f = ref_obs[3]
    bx, by, bz = unproject_pixel(params, uc, vc)
    depth = triangulate_depth(T_cur_ref, f, np.array([bx, by, bz]))
    if depth <= 0.0:
        return False, 0.0, 0.0, uc, vc
    tau = inverse_depth_sigma(T_cur_ref, f, depth, px_angle * 2.0 ** lv)
    return True, 1.0 / depth, tau, uc, vc


@numba.njit(cache=True, nogil=True)
def in_view(params, T_cur_ref, f, rho, sigma, width, height):
    """True when the point on bearing f of a reference camera projects inside a width x height
    image at T_cur_ref at some inverse depth of its range rho +- 2 sigma (its mean, nearest
    or farthest): where the epipolar search could find it."""
    for r in (rho, rho + 2.0 * sigma, max(rho - 2.0 * sigma, MIN_RHO)):
        x, y, z = transform(T_cur_ref, f[0] / r, f[1] / r, f[2] / r)
        if z > 0.0:
            u, v = project_point(params, x, y, z)
            if 0.0 <= u < width and 0.0 <= v < height:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def update_candidates(params, points, idx, keyframes, T_c_w, layout, cur_flat, corners, search,
                      update, orb, dry_run):
    """Search every candidate idx in the current frame (pose T_c_w, pyramid `cur_flat`, FAST
    `corners`) and fold the result into its filter (with `dry_run`, only search: an ORB pass
    that collects the descriptors it needs).

    `points` is the point table (host, u, v, level, f, rho, sigma, a, b, rho_range, n_failed,
    n_updates, status, pos_w: PointStore columns, updated in place), `keyframes` the (pyramids,
    T_c_w) of the map's slots, `layout` the pyramids' (offsets, widths, heights), `search` as
    for match_epipolar, `update` = (px_angle, max_failures, min_inlier, conv_L, skip_unseen): the
    angle of a pixel, failed searches before a point is dropped, the inlier probability below
    which it is dropped, the linearity index below which it has converged, and whether points
    out of the frame's view are left alone.

    Returns (found mask, level-0 positions (N, 2), delete mask)."""
    host, u, v, level, f, rho, sigma, a, b, rho_range, n_failed, n_updates, status, pos_w = (
        points)
    kf_pyr, kf_T_c_w = keyframes
    px_angle, max_failures, min_inlier, conv_L, skip_unseen = update
    n = idx.shape[0]
    found = np.zeros(n, dtype=np.bool_)
    uv = np.zeros((n, 2))
    delete = np.zeros(n, dtype=np.bool_)
    cam_pos = -(np.ascontiguousarray(T_c_w[:3, :3].T) @ np.ascontiguousarray(T_c_w[:3, 3]))
    for k in range(n):
        p = idx[k]
        T_w_h = inv_se3(kf_T_c_w[host[p]])
        T_cur_ref = T_c_w @ T_w_h
        if skip_unseen and not in_view(params, T_cur_ref, f[p], rho[p], sigma[p],
                                       layout[1][0], layout[2][0]):
            continue  # out of view: not searched, so no failed search (thesis 6.6.3)
        ok, x, tau, uc, vc = _measure(params, layout, kf_pyr[host[p]],
                                      (u[p], v[p], level[p], f[p]), rho[p], sigma[p], T_cur_ref,
                                      cur_flat, corners, search, px_angle, query(orb, k))
        if dry_run:
            continue
        if not ok:
            n_failed[p] += 1
            delete[k] = n_failed[p] > max_failures
            continue
        m, s2, aa, bb = update_seed(rho[p], sigma[p] ** 2, a[p], b[p], x, tau * tau,
                                    rho_range[p])
        if m <= 0.0:
            delete[k] = True
            continue
        rho[p], sigma[p], a[p], b[p] = m, np.sqrt(s2), aa, bb
        n_failed[p] = 0
        n_updates[p] += 1
        found[k] = True
        uv[k, 0], uv[k, 1] = uc, vc
        pos_w[p] = np.ascontiguousarray(T_w_h[:3, :3]) @ (f[p] / m) + T_w_h[:3, 3]
        if aa / (aa + bb) < min_inlier:
            delete[k] = True
            continue
        ray_h = pos_w[p] - T_w_h[:3, 3]
        ray_c = pos_w[p] - cam_pos
        d = np.sqrt(ray_c @ ray_c)
        cos_par = (ray_h @ ray_c) / (np.sqrt(ray_h @ ray_h) * d)
        if linearity_index(m, np.sqrt(s2), d, cos_par) < conv_L:
            status[p] = CONVERGED
    return found, uv, delete


@numba.njit(cache=True, nogil=True)
def search_new(params, layout, ref_flat, features, prior, T_cur_ref, cur_flat, corners, search,
               px_angle, orb):
    """Search the new candidates of the reference keyframe still without a depth (rho NaN) in
    another keyframe; a match is the first depth-filter update of the prior (rho0 +- sigma0,
    Beta(a0, b0), range rho_range) and sets rho, sigma in place. `features` = (u, v, level, f,
    rho, sigma) columns of the candidates, `prior` = (rho0, sigma0, a0, b0, rho_range), the
    rest as for _measure. One kernel for all of them: no GIL round trip per point. `orb`:
    tables of vo.orb for feature k (as for match_epipolar)."""
    u, v, level, f, rho, sigma = features
    rho0, sigma0, a0, b0, rho_range = prior
    for k in range(u.shape[0]):
        if not np.isnan(rho[k]):
            continue
        found, x, tau, _, _ = _measure(params, layout, ref_flat, (u[k], v[k], level[k], f[k]),
                                       rho0, sigma0, T_cur_ref, cur_flat, corners, search,
                                       px_angle, query(orb, k))
        if not found:
            continue
        m, s2, _, _ = update_seed(rho0, sigma0 ** 2, a0, b0, x, tau * tau, rho_range)
        if m > 0.0:
            rho[k], sigma[k] = m, np.sqrt(s2)


class Mapper:
    """One mapping step per frame: update candidates, and on keyframes extend the map."""

    def __init__(self, camera, config: TrackerConfig, map_: Map):
        self.camera = camera
        self.config = config
        self.map = map_
        self.px_angle = 2.0 * np.arctan(0.5 / np.sqrt(camera.fx * camera.fy))
        self.n_keyframes_added = 0
        # frames mapped since the last keyframe added: its candidates' depth updates so far
        self.frames_since_keyframe = 0
        # the tracker says whether there is time for a bundle adjustment (threaded: no frame
        # waiting); skipped ones are counted
        self.ba_allowed: Callable[[], bool] = lambda: True
        self.skipped_ba = 0
        self.shortened_ba = 0  # BAs ended early because a frame came (threaded)
        self._ba_cut = False
        # called with the keyframes a BA moved (slot -> (T_c_w before, after)) while the map
        # lock is held: the tracker moves its last pose along
        self.after_ba: Callable[[dict], None] = lambda moved: None
        # called between the BA solver's steps: waits while the tracker tracks a frame
        self.ba_pause: Callable[[], None] = lambda: None
        # called with each frame before its step (threaded mapping only): a service holds the
        # mapping thread here until the frame's estimate is on its way (daemon.tracking)
        self.before_step: Callable[[Frame], None] = lambda frame: None
        # after each step: joins a map re-initialisation replaced (vo.map_merge), if any
        self.merge_step: Callable[[Frame, Map], None] = lambda frame, map_: None

    def _target(self, frame: Frame) -> tuple:
        """What a search in `frame` takes: (pyramid layout, flat pyramid, FAST corners,
        search settings of vo.matcher.match_epipolar)."""
        c = frame.corners(self.config.fast_threshold)
        cfg = self.config
        search = (0, cfg.match_max_level, cfg.epipolar_margin_px, cfg.zmssd_threshold,
                  cfg.align2d_iterations)
        return frame.pyr.layout, frame.pyr.flat, c.tables, search

    def step(self, frame: Frame, keyframe: bool) -> None:
        """Process one tracked frame (and make it a keyframe when asked)."""
        self.before_step(frame)
        pts = self.map.points
        with self.map.lock:
            if pts.step(frame.id):
                # observations of freed slots must go before the slots are reused
                self.map.prune_observations()
        cand = np.flatnonzero(pts.status == CANDIDATE)
        cand = cand[pts.host[cand] != frame.slot]
        found_uv = np.zeros((0, 2))
        if len(cand):
            found_uv = self._update_candidates(frame, cand)
        if keyframe:
            self.add_keyframe(frame, found_uv)
        else:
            self.frames_since_keyframe += 1
        self.merge_step(frame, self.map)

    def _update_candidates(self, frame: Frame, cand: np.ndarray) -> np.ndarray:
        """Depth-filter update of candidate points `cand` from their matches in frame; the
        level-0 pixels where the points still in the map were found."""
        cfg = self.config
        pts = self.map.points
        layout, flat, corners, search = self._target(frame)
        orb = self._orb_query(frame, cand, pts.desc, pts.desc_state, self._describe_points)
        table = (pts.host, pts.u, pts.v, pts.level, pts.f, pts.rho, pts.sigma, pts.a, pts.b,
                 pts.rho_range, pts.n_failed, pts.n_updates, pts.status, pts.pos_w)
        update = (self.px_angle, cfg.seed_max_failures, cfg.min_inlier_probability,
                  cfg.convergence_L, cfg.seed_skip_unseen)

        def search_all(dry_run: bool):
            return update_candidates(self.camera.params, table, cand,
                                     (self.map.kf_pyr, self.map.kf_T_c_w), frame.T_c_w, layout,
                                     flat, corners, search, update, orb.tables, dry_run)

        if orb.max_distance >= 0:
            search_all(True)
            orb.fill()
        found, uv, delete = search_all(False)
        with self.map.lock:
            pts.delete(cand[delete])
        return uv[found & ~delete]

    def add_keyframe(self, frame: Frame, occupied_uv: np.ndarray) -> None:
        """Insert `frame` as a keyframe, seed candidates in its empty cells, cap keyframes."""
        cfg = self.config
        pts = self.map.points
        depth, frame.depth = frame.depth, None  # a keyframe keeps no depth map
        with self.map.lock:
            slot = self.map.add_keyframe(frame)
        self.n_keyframes_added += 1
        self.frames_since_keyframe = 0
        depths = self.scene_depths(frame)
        if len(depths) == 0:
            return
        d_med, d_min = float(np.median(depths)), float(np.min(depths))
        u, v, level = self.new_features(frame, np.vstack((frame.feat_px, occupied_uv)))
        if len(u) == 0:
            return
        f = self.camera.unproject(np.column_stack((u, v)))
        T_w_new = frame.T_w_c
        rho, sigma = np.full(len(u), np.nan), np.full(len(u), np.nan)
        if depth is not None:  # measured depths; the other features are searched as before
            rho, sigma = measured_inverse_depth(depth, np.column_stack((u, v)), f, cfg)
        rho0 = 1.0 / d_med
        prior = (rho0, cfg.seed_sigma_ratio * rho0, cfg.seed_a, cfg.seed_b, 1.0 / d_min)
        searched = self._search_keyframes(frame, slot)
        desc, desc_state = self._seed_depths(frame, searched, (u, v, level, f, rho, sigma),
                                             prior)
        if cfg.seed_plane_sigma > 0:
            self._seed_on_plane(frame, f, rho, sigma)
        if cfg.seed_unmatched_prior:
            self._seed_unseen(frame, searched, f, rho, sigma, prior)
        new = np.flatnonzero(np.isfinite(rho))
        with self.map.lock:
            ids = pts.add(slot, u[new], v[new], level[new], f[new], rho[new], sigma[new],
                          np.full(len(new), 1.0 / d_min), cfg.seed_a, cfg.seed_b, T_w_new)
            pts.desc[ids], pts.desc_state[ids] = desc[new], desc_state[new]
            self._cap_keyframes(frame)
            if self.n_keyframes_added % 10 == 0:
                self.map.prune_observations()
        if cfg.local_ba and self.ba_allowed():
            self._ba_cut = False
            local_ba(self.map, slot, self.camera, cfg, self._stop_ba, self.after_ba,
                     self.ba_pause)
            self.shortened_ba += int(self._ba_cut)
        else:
            self.skipped_ba += int(cfg.local_ba)

    def _seed_depths(self, frame: Frame, searched: list[int], features: tuple,
                     prior: tuple) -> tuple[np.ndarray, np.ndarray]:
        """Search new features (u, v, level, f, rho, sigma; rho NaN) of keyframe `frame` in the
        keyframe slots `searched` (_search_keyframes) until each has a depth: a match is the
        first update of the depth filter from `prior` (rho0, sigma0, a0, b0, rho_range), set in
        rho, sigma. Returns the ORB descriptors (and their states) computed for the features
        meanwhile."""
        u, v, _, _, rho, _ = features
        levels = self.config.pyramid_levels
        desc = np.zeros((len(u), levels, DESC_BYTES), dtype=np.uint8)
        desc_state = np.zeros((len(u), levels), dtype=np.int8)

        def describe_new(rows: np.ndarray, need: np.ndarray) -> None:
            d, st = desc[rows], desc_state[rows]
            describe_levels(frame.pyr.images, u[rows], v[rows], need, d, st)
            desc[rows], desc_state[rows] = d, st

        T_w_new = frame.T_w_c
        for other in searched:
            if not np.isnan(rho).any():
                break
            kf = self.map.keyframes[other]
            orb = self._orb_query(kf, np.arange(len(u)), desc, desc_state, describe_new)
            layout, flat, corners, search = self._target(kf)
            args = (self.camera.params, layout, frame.pyr.flat, features, prior,
                    kf.T_c_w @ T_w_new, flat, corners, search, self.px_angle)
            search_new(*args, orb.tables)
            if orb.fill():  # an ORB pass matches what it can and collects what it needs
                search_new(*args, orb.tables)
        return desc, desc_state

    def _seed_on_plane(self, frame: Frame, f: np.ndarray, rho: np.ndarray,
                       sigma: np.ndarray) -> None:
        """Give the new candidates without a depth (rho NaN) the inverse depth where their ray
        meets the plane of frame's converged points, if those points lie on a plane."""
        cfg = self.config
        pts = self.map.points
        ids = frame.feat_point[pts.status[frame.feat_point] == CONVERGED]
        X = pts.pos_w[ids] @ frame.T_c_w[:3, :3].T + frame.T_c_w[:3, 3]
        plane = fit_plane(X, PLANE_FIT_TOLERANCE, cfg.seed_plane_min_fit)
        if plane is None:
            return
        normal, offset = plane
        along = f @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            r = along / offset  # inverse range along each bearing to the plane
        fill = np.isnan(rho) & (r > 0)
        rho[fill] = r[fill]
        sigma[fill] = cfg.seed_plane_sigma * r[fill]

    def _seed_unseen(self, frame: Frame, searched: list[int], f: np.ndarray, rho: np.ndarray,
                     sigma: np.ndarray, prior: tuple) -> None:
        """Start the new candidates no keyframe matched (rho NaN) from the depth prior (rho0,
        sigma0) when the keyframes `searched` looked their way (their bearing is in view of one)
        but had them out of view at the scene's depth, and they are at least
        seed_prior_min_share of the new candidates: ground a climb uncovers at the image's
        edges. Those a keyframe had in view and did not match, and those a turn brings in,
        stay dropped (6.6.2)."""
        rho0, sigma0 = prior[0], prior[1]
        R_w_c, centre = frame.T_w_c[:3, :3], frame.T_w_c[:3, 3]
        ray_w = f @ R_w_c.T
        looked = np.zeros(len(f), dtype=bool)
        unseen = np.isnan(rho)
        for other in searched:
            T = self.map.keyframes[other].T_c_w
            looked |= self._in_view(ray_w @ T[:3, :3].T)
            unseen &= ~self._in_view((ray_w / rho0 + centre) @ T[:3, :3].T + T[:3, 3])
        fill = unseen & looked
        if fill.sum() >= self.config.seed_prior_min_share * len(f):
            rho[fill], sigma[fill] = rho0, sigma0

    def _in_view(self, X: np.ndarray) -> np.ndarray:
        """Camera-frame points (or directions) X in front of the camera and inside its image."""
        seen = np.zeros(len(X), dtype=bool)
        ahead = X[:, 2] > 0
        seen[ahead] = self.camera.in_image(self.camera.project(X[ahead]))
        return seen

    def _stop_ba(self) -> bool:
        """True once tracking has a frame waiting: the BA ends early rather than fall
        behind."""
        self._ba_cut = self._ba_cut or not self.ba_allowed()
        return self._ba_cut

    def _orb_query(self, frame: Frame, pid: np.ndarray, desc: np.ndarray,
                   desc_state: np.ndarray, fill_refs) -> OrbQuery:
        """ORB arguments for searching references `pid` (rows of desc) in frame's corners
        (patch matching: a dummy)."""
        cfg = self.config
        if cfg.matcher != "orb":
            return OrbQuery.patches(len(pid), cfg.pyramid_levels)
        return OrbQuery(cfg.orb_max_distance, pid, desc, desc_state, cfg.pyramid_levels,
                        frame.orb, frame.corners(cfg.fast_threshold), fill_refs)

    def _describe_points(self, ids: np.ndarray, need: np.ndarray) -> None:
        with self.map.lock:
            self.map.describe_points(ids, need)

    def scene_depths(self, frame: Frame) -> np.ndarray:
        """Depths in frame of the map points it matched (those in front of it)."""
        pts = self.map.points
        if len(frame.feat_point) == 0:
            return np.zeros(0)
        X = pts.pos_w[frame.feat_point] @ frame.T_c_w[:3, :3].T + frame.T_c_w[:3, 3]
        return X[:, 2][X[:, 2] > 0]

    def _search_keyframes(self, frame: Frame, slot: int) -> list[int]:
        """Covisible keyframes (>= covisible_min_shared points), else the nearest one."""
        slots = self.map.covisible(frame.feat_point, slot, self.config.covisible_min_shared)
        if not slots:
            others = [s for s in self.map.keyframes if s != slot]
            if others:
                slots = [min(others, key=lambda s: np.linalg.norm(
                    self.map.keyframes[s].position - frame.position))]
        return slots

    def new_features(self, frame: Frame, occupied_uv: np.ndarray):
        """One corner per empty grid cell, the best Shi-Tomasi score over all levels."""
        cfg = self.config
        c = frame.corners(cfg.fast_threshold)
        pyr = frame.pyr
        score = shi_tomasi(pyr.flat, pyr.offsets, pyr.widths, pyr.heights, c.level, c.x, c.y)
        x, y = c.level0()
        cols = (self.camera.width + cfg.grid_cell - 1) // cfg.grid_cell
        rows = (self.camera.height + cfg.grid_cell - 1) // cfg.grid_cell
        occupied = np.zeros(cols * rows, dtype=bool)
        if len(occupied_uv):
            oc = np.clip((occupied_uv // cfg.grid_cell).astype(np.int64), 0, [cols - 1, rows - 1])
            occupied[oc[:, 1] * cols + oc[:, 0]] = True
        margin = 2.0 ** c.level * 6
        ok = (score > 0) & (x >= margin) & (y >= margin) & (x < self.camera.width - margin) & (
            y < self.camera.height - margin)
        cell = (y // cfg.grid_cell).astype(np.int64) * cols + (x // cfg.grid_cell).astype(np.int64)
        ok &= ~occupied[np.clip(cell, 0, len(occupied) - 1)]
        sel = np.flatnonzero(ok)
        best = sel[best_per_cell(x[sel], y[sel], score[sel], cfg.grid_cell, self.camera.width)]
        return x[best], y[best], c.level[best]

    def _cap_keyframes(self, frame: Frame) -> None:
        keep = {frame.slot}
        while len(self.map) > self.config.max_keyframes:
            slot = self.map.farthest_keyframe(frame.position, keep)
            if slot is None:
                break
            self.map.remove_keyframe(slot)


def fit_plane(X: np.ndarray, tolerance: float, min_fit: float,
              rounds: int = 3) -> tuple[np.ndarray, float] | None:
    """The plane n . X = d (unit n, d > 0: the camera at the origin is off it) through points
    X (N, 3) in a camera frame, refitted to the points near it a few times; None when fewer
    than min_fit of the points are within tolerance * distance of it (not a plane) or there
    are too few points."""
    if len(X) < MIN_PLANE_POINTS:
        return None
    dist = np.linalg.norm(X, axis=1)
    near = np.ones(len(X), dtype=bool)
    for _ in range(rounds):
        if near.sum() < 3:
            return None
        centre = X[near].mean(axis=0)
        D = X[near] - centre
        normal = np.linalg.eigh(D.T @ D)[1][:, 0]  # least-spread direction
        off = np.abs((X - centre) @ normal)
        near = off < max(3.0 * float(np.median(off)), 1e-9)
    if np.mean(off < tolerance * dist) < min_fit:
        return None
    d = float(centre @ normal)
    return (normal, d) if d > 0 else (-normal, -d)
