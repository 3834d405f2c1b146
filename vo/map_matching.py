"""Matching the map in a frame whose pose prior is set (thesis 6.7.2-6.8): project and match map
points (vo.reprojector), optionally RANSAC outlier rejection with a rescue, Tukey Gauss-Newton
pose refinement (vo.pose_optimizer); the quality of 6.10 from the result, and the points'
found / missed bookkeeping once a frame's pose is accepted."""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import numba
import numpy as np

from calib.camera import CameraModel
from vo import outlier_rejection
from vo.config import TrackerConfig
from vo.depth_segments import segment_distances
from vo.frame import Frame
from vo.map import CANDIDATE, CONVERGED, Map
from vo.pose_optimizer import depth_whitening, optimize_pose
from vo.quality import classify
from vo.reprojector import Reprojector
from vo.result import Quality, ms_since
from vo.se3 import orthonormalized

MIN_POSE_MATCHES = 6


@dataclass
class Matches:
    """One frame's matched map points and the pose refined from them."""

    ids: np.ndarray
    uv: np.ndarray
    levels: np.ndarray
    n_visible: int  # grid cells the usable map points project into
    n_attempts: int
    attempted: np.ndarray
    inlier: np.ndarray
    T: np.ndarray
    H: np.ndarray | None
    sigma: float
    n_hypotheses: int = 0
    # matches consistent with the pose along their depth intervals whether or not outlier
    # rejection let them into it (MapMatcher._along); counted only with hold_frames and for
    # a frame that is not good (0 otherwise)
    n_along: int = 0

    @property
    def n_inliers(self) -> int:
        """Matches that survived the pose refinement."""
        return int(self.inlier.sum())


class MapMatcher:
    """Matches one map's points in frames and refines their poses from the matches."""

    def __init__(self, camera: CameraModel, config: TrackerConfig, map_: Map,
                 reprojector: Reprojector):
        self.camera, self.config, self.map, self.reprojector = camera, config, map_, reprojector
        self.focal = float(np.sqrt(camera.fx * camera.fy))
        self.ransac_px, self.rescue_px = config.ransac_pixels(camera.width)

    def match(self, frame: Frame, timings: dict[str, float]) -> Matches:
        """Map points matched in frame (pose prior set) and the pose refined from them."""
        cfg = self.config
        if cfg.track_candidates or cfg.track_search_fallback or cfg.matcher == "orb":
            t0 = time.perf_counter()
            # searches among corners
            frame.corners(cfg.fast_threshold, cfg.track_corner_level, cfg.match_max_level)
            timings["corners"] = ms_since(t0)
        t0 = time.perf_counter()
        ids, uv, levels, n_visible, n_attempts, attempted = self._reproject(frame)
        timings["reproject"] = ms_since(t0)
        m = Matches(ids, uv, levels, n_visible, n_attempts, attempted,
                    np.zeros(len(ids), dtype=bool), frame.T_c_w, None, 0.0)
        if len(ids) < MIN_POSE_MATCHES:
            return m
        t0 = time.perf_counter()
        self._refine(frame, m, timings)
        timings["pose"] = ms_since(t0)
        return m

    def _refine(self, frame: Frame, m: Matches, timings: dict[str, float]) -> None:
        """m's pose from its matches (with outlier rejection: RANSAC, then the rescue) and its
        inliers. The matches' normalised coordinates and depth whitening (both at frame's
        prior pose) are computed once for all the fits, and so is the fit to all matches (the
        pose without rejection, RANSAC's first hypothesis, its fallback)."""
        cfg, ids, levels = self.config, m.ids, m.levels
        obs, whiten = self.normalised(m.uv), self._whitening(frame.T_c_w, ids)
        whole = self._fit(frame, ids, obs, levels, whiten)  # needed on every path

        def fit(use: np.ndarray):
            return whole if use.all() else self._fit(frame, ids[use], obs[use], levels[use],
                                                     whiten[use])

        use = np.ones(len(ids), dtype=bool)
        rejecting = cfg.outlier_rejection and len(ids) > outlier_rejection.SUBSET
        if rejecting:
            t0 = time.perf_counter()
            judged = self._judged(ids, whiten)  # RANSAC's
            use, m.n_hypotheses = self._reject_outliers(frame, ids, obs, levels, judged,
                                                         whole[0])
            timings["ransac"] = ms_since(t0)
            if use.sum() < MIN_POSE_MATCHES:
                # no consensus within image pixels (blurred matches found on coarse levels):
                # the robust fit to all matches decides, as without rejection
                use[:], rejecting = True, False
        if use.sum() < MIN_POSE_MATCHES:
            return
        T, H, sigma, err = fit(use)
        if rejecting:
            # rescue: outliers within a wider threshold of the inlier pose join them
            rescue = self._rescue_judged(ids, whiten, judged)
            use = self._errors(ids, obs, rescue, T) * self.focal < self.rescue_px
            T, H, sigma, err = fit(use)
        m.T, m.H, m.sigma = T, H, sigma
        m.inlier[use] = err * self.focal < cfg.reprojection_inlier_px
        if cfg.hold_frames and self.quality(m) != Quality.GOOD:
            m.n_along = self._along(ids, obs, levels, T)

    def quality(self, m: Matches) -> Quality:
        """Quality of 6.10; a match counts once it survives the pose refinement."""
        if m.n_inliers < MIN_POSE_MATCHES:
            return Quality.BAD
        return classify(m.n_inliers, m.n_attempts, self.config)

    def held(self, m: Matches) -> bool:
        """Whether the pose of a frame not to be published (from at least MIN_POSE_MATCHES
        inliers) is worth keeping to track on from (hold_frames): counting the matches
        consistent with it along their depth intervals, it would not be bad. A candidate whose
        interval reaches out to infinity confirms a fast turn, not how far the camera moved:
        such a pose is never published (vo.frame_tracking)."""
        if not self.config.hold_frames or m.n_inliers < MIN_POSE_MATCHES:
            return False
        return classify(max(m.n_inliers, m.n_along), m.n_attempts,
                        self.config) != Quality.BAD

    def accept(self, frame: Frame, m: Matches, count: bool = True) -> None:
        """Give frame its refined pose and matches; with `count`, update the points'
        found/missed counts (see count)."""
        ids, inlier = m.ids, m.inlier
        frame.T_c_w = orthonormalized(m.T)
        frame.pose_info = m.H
        frame.set_features(ids[inlier], m.uv[inlier], m.levels[inlier])
        frame.n_visible = m.n_visible
        if count:
            self.count(m)

    def count(self, m: Matches) -> None:
        """Update the found/missed/unmatched (and rejected) counts of the points of an
        accepted frame's matches m; points that keep failing leave the map."""
        cfg = self.config
        pts = self.map.points
        hopeless = _count_found_missed(pts.n_found, pts.n_missed, pts.n_unmatched, m.ids,
                                       m.inlier, m.attempted, cfg.point_max_missed)
        if cfg.outlier_rejection:
            self._forget_rejected(m.ids, m.inlier)
        pts.delete(hopeless)

    def optimize(self, frame: Frame, ids: np.ndarray, uv: np.ndarray, levels: np.ndarray):
        """Pose refinement from matches from frame's pose (and its rotation prior); returns
        (T_c_w, H, sigma, per-match error)."""
        return self._fit(frame, ids, self.normalised(uv), levels,
                         self._whitening(frame.T_c_w, ids))

    def optimize_from(self, T_c_w: np.ndarray, ids: np.ndarray, uv: np.ndarray,
                      levels: np.ndarray):
        """optimize from the pose T_c_w, without a rotation prior."""
        return self._solve(T_c_w, np.eye(3), 0.0, ids, self.normalised(uv), levels,
                           self._whitening(T_c_w, ids))

    def _along(self, ids: np.ndarray, obs: np.ndarray, levels: np.ndarray,
               T_c_w: np.ndarray) -> int:
        """How many matches (normalised obs) lie within reprojection_inlier_px, at their level,
        of the segment their point's 2-sigma inverse-depth interval projects to at pose T_c_w
        (vo.depth_segments)."""
        pts = self.map.points
        d = segment_distances(T_c_w, self.map.kf_T_c_w, pts.host[ids], pts.f[ids],
                              pts.rho[ids], 2.0 * pts.sigma[ids], obs)
        return int((d * self.focal / 2.0 ** levels < self.config.reprojection_inlier_px).sum())

    def _whitening(self, T_c_w: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """The matches' error whitening along their depth intervals at the pose T_c_w."""
        pts = self.map.points
        return depth_whitening(T_c_w, self.map.kf_T_c_w, pts.host[ids], pts.f[ids],
                               pts.rho[ids], pts.sigma[ids], 1.0 / self.focal)

    def _fit(self, frame: Frame, ids: np.ndarray, obs: np.ndarray, levels: np.ndarray,
             whiten: np.ndarray):
        """optimize from normalised coordinates obs and whitening already computed."""
        return self._solve(frame.T_c_w, frame.R_prior, frame.prior_info, ids, obs, levels,
                           whiten)

    def _solve(self, T_c_w: np.ndarray, R_prior: np.ndarray, prior_info: float,
               ids: np.ndarray, obs: np.ndarray, levels: np.ndarray, whiten: np.ndarray):
        """The robust pose (vo.pose_optimizer) from T_c_w and the rotation prior."""
        return optimize_pose(np.ascontiguousarray(self.map.points.pos_w[ids]), obs,
                             np.ascontiguousarray(levels, dtype=np.int64), whiten, T_c_w,
                             self.config.pose_iterations, 0.5 / self.focal, R_prior, prior_info)

    def normalised(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised image-plane coordinates of level-0 pixels."""
        f = self.camera.unproject(uv)
        return np.ascontiguousarray(f[:, :2] / f[:, 2:])

    def usable_points(self) -> np.ndarray:
        """Ids of the points tracking matches: converged, and (track_candidates) candidates
        updated candidate_min_updates times."""
        cfg = self.config
        pts = self.map.points
        usable = pts.status == CONVERGED
        if cfg.track_candidates:
            usable |= (pts.status == CANDIDATE) & (pts.n_updates >= cfg.candidate_min_updates)
        return np.flatnonzero(usable)

    def _reproject(self, frame: Frame):
        idx = self.usable_points()
        search = self.map.points.status[idx] == CANDIDATE
        return self.reprojector.run(frame, self.map, idx, search)

    def _errors(self, ids: np.ndarray, obs: np.ndarray, judged: np.ndarray,
                T_c_w: np.ndarray) -> np.ndarray:
        """Reprojection errors (normalised plane) of matches (normalised obs) at pose T_c_w,
        whitened by `judged` (_judged) as RANSAC judges them."""
        pos = np.ascontiguousarray(self.map.points.pos_w[ids])
        return np.sqrt(outlier_rejection.squared_errors(pos, obs, judged, T_c_w))

    def _judged(self, ids: np.ndarray, whiten: np.ndarray) -> np.ndarray:
        """The whitening RANSAC (and the rescue, before _rescue_judged) judges the matches of
        points ids by: none without ransac_depth_whitening; with it the depth whitening, of
        every match or (a ransac_whitening_min_inlier above 0) only of candidates the depth
        filter holds at least that likely inliers."""
        cfg = self.config
        plain = np.broadcast_to(np.eye(2), whiten.shape).copy()
        if not cfg.ransac_depth_whitening:
            return plain
        if cfg.ransac_whitening_min_inlier <= 0.0:
            return whiten
        keep = self._likely_candidates(ids, cfg.ransac_whitening_min_inlier)
        plain[keep] = whiten[keep]
        return plain

    def _rescue_judged(self, ids: np.ndarray, whiten: np.ndarray,
                       judged: np.ndarray) -> np.ndarray:
        """The whitening the rescue judges the matches of points ids by: RANSAC's, and with
        rescue_depth_whitening the depth whitening for the candidates the depth filter holds
        at least rescue_whitening_min_inlier likely inliers (such a candidate's match may lie
        anywhere along its depth interval, as the pose refinement allows; a mover's depth
        keeps failing its filter)."""
        cfg = self.config
        if not cfg.rescue_depth_whitening:
            return judged
        keep = self._likely_candidates(ids, cfg.rescue_whitening_min_inlier)
        out = judged.copy()
        out[keep] = whiten[keep]
        return out

    def _likely_candidates(self, ids: np.ndarray, min_inlier: float) -> np.ndarray:
        """Which points of ids are candidates their depth filter holds at least min_inlier
        likely inliers (a / (a + b))."""
        pts = self.map.points
        likely = pts.a[ids] >= min_inlier * (pts.a[ids] + pts.b[ids])
        return likely & (pts.status[ids] == CANDIDATE)

    def _reject_outliers(self, frame: Frame, ids: np.ndarray, obs: np.ndarray,
                         levels: np.ndarray, judged: np.ndarray,
                         T_all: np.ndarray) -> tuple[np.ndarray, int]:
        """RANSAC inliers (6.8) among the matches, hypotheses from frame's prior pose; and
        how many hypotheses were fitted. T_all, the robust pose from all matches, is the first
        hypothesis: 5-point fits to matches a few pixels off agree with few others (kitti00
        with its preset 1.06 -> 0.62 m with it)."""
        cfg = self.config
        draw = partial(outlier_rejection.random_subsets, len(ids), seed=cfg.seed + frame.id)
        inlier, tried = outlier_rejection.ransac(
            np.ascontiguousarray(self.map.points.pos_w[ids]), obs, judged,
            1.0 / 2.0 ** levels, frame.T_c_w, draw, self.ransac_px / self.focal,
            cfg.ransac_probability, cfg.ransac_max_hypotheses, T_all)
        return inlier, int(tried)

    def _forget_rejected(self, ids: np.ndarray, inlier: np.ndarray) -> None:
        """Map hygiene of outlier rejection (6.8): matched points the pose rejects in
        point_max_rejected tracked frames in a row have moved or were badly placed; they leave
        the map instead of being matched (and rejected) again in every frame."""
        pts = self.map.points
        pts.n_rejected[ids[inlier]] = 0
        rejected = ids[~inlier]
        pts.n_rejected[rejected] += 1
        pts.delete(rejected[pts.n_rejected[rejected] >= self.config.point_max_rejected])



@numba.njit(cache=True, nogil=True)
def _count_found_missed(n_found, n_missed, n_unmatched, ids, inlier, attempted, max_missed):
    """MapMatcher.count's counts: +1 found for the inliers among the matched points ids, +1
    missed for the attempted points not matched, and the streak n_unmatched of frames in a
    row an attempted point was not matched (0 for the matched); returns those missed that
    keep failing (occluded, badly placed, moving: more than max_missed misses and twice their
    finds), which leave the map. `attempted` is sorted; so is the result."""
    matched = np.zeros(n_found.shape[0], dtype=np.bool_)
    for p in attempted:
        n_unmatched[p] += 1
    for j in range(ids.shape[0]):
        matched[ids[j]] = True
        n_unmatched[ids[j]] = 0
        if inlier[j]:
            n_found[ids[j]] += 1
    hopeless = np.empty(attempted.shape[0], dtype=np.int64)
    n = 0
    for p in attempted:
        if matched[p]:
            continue
        n_missed[p] += 1
        if n_missed[p] > max_missed and n_missed[p] > 2 * n_found[p]:
            hopeless[n] = p
            n += 1
    return hopeless[:n]
