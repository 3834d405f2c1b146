"""The SDVL tracker (thesis 6.1): frames in, world-from-camera poses out.

Tracking per frame (6.7): constant-velocity prior, sparse image alignment to the last frame,
grid-limited matching of map points, Tukey Gauss-Newton pose, quality (6.10). Mapping (6.6)
runs after each frame (sequential, reproducible) or in its own thread with a bounded queue.
"""

from __future__ import annotations

import queue
import threading
import time

import numpy as np

from calib.camera import CameraModel
from calib.errors import InputError
from vo import sparse_align
from vo.config import TrackerConfig
from vo.depth_filter import converged
from vo.frame import Frame
from vo.initialization import Initializer, InitialMap
from vo.map import CANDIDATE, CONVERGED, Map
from vo.mapping import Mapper
from vo.matcher import inverse_depth_sigma
from vo.pose_optimizer import depth_whitening, optimize_pose, pose_covariance
from vo.quality import LostCounter, classify
from vo.reprojector import Reprojector
from vo.result import FrameResult
from vo.se3 import inv_se3, orthonormalized

MIN_POSE_MATCHES = 6


class Tracker:
    """Monocular SDVL tracker for one camera."""

    def __init__(self, camera: CameraModel, config: TrackerConfig | None = None,
                 threaded: bool = False):
        self.camera = camera
        self.config = config or TrackerConfig()
        self.threaded = threaded
        self.dropped_mapping_frames = 0
        self._mapping_error: Exception | None = None
        self._frame_id = 0
        self._queue: queue.Queue | None = None
        self._thread: threading.Thread | None = None
        self.reprojector = Reprojector(camera, self.config.grid_cell, self.config.seed)
        self._reset()

    # ------------------------------------------------------------------ lifecycle
    def _reset(self) -> None:
        """Forget the map and start initialising again."""
        self._stop_thread()
        cfg = self.config
        self.map = Map(self.camera.width, self.camera.height, cfg.pyramid_levels,
                       cfg.max_keyframes)
        self.mapper = Mapper(self.camera, cfg, self.map)
        self.initializer = Initializer(self.camera, cfg)
        self.last: Frame | None = None
        self.motion = np.eye(4)
        self.lost = LostCounter(cfg)
        self.frames_since_kf = 0
        self.kf_visible = 0
        if self.threaded:
            self._queue = queue.Queue(maxsize=cfg.mapping_queue_size)
            self._thread = threading.Thread(target=self._mapping_loop, name="sdvl-mapping",
                                            daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop the mapping thread (if any)."""
        self._stop_thread()

    def _stop_thread(self) -> None:
        if self._thread is not None and self._queue is not None:
            self._queue.put(None)
            self._thread.join()
        self._thread = None

    def _mapping_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._mapping_error is not None:
                continue  # keep draining so the tracking thread never blocks on the queue
            try:
                self.mapper.step(*item)
            except Exception as exc:  # re-raised in the tracking thread by process()
                self._mapping_error = exc

    def _map_step(self, frame: Frame, keyframe: bool) -> None:
        if not self.threaded:
            self.mapper.step(frame, keyframe)
            return
        if keyframe:
            self._queue.put((frame, True))
            return
        try:
            self._queue.put_nowait((frame, False))
        except queue.Full:
            self.dropped_mapping_frames += 1

    # ------------------------------------------------------------------ per frame
    def process(self, image: np.ndarray, t: float) -> FrameResult:
        """Track one grey uint8 image taken at time t (seconds)."""
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 2:
            raise InputError(f"tracker needs a 2-D uint8 grey image, got {image.dtype} "
                             f"{image.shape}")
        if image.shape != (self.camera.height, self.camera.width):
            raise InputError(f"image is {image.shape[1]}x{image.shape[0]}, camera is "
                             f"{self.camera.width}x{self.camera.height}")
        if self._mapping_error is not None:
            raise RuntimeError("the mapping thread failed") from self._mapping_error
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        frame = Frame(self._frame_id, float(t), image, self.camera, self.config.pyramid_levels)
        self._frame_id += 1
        timings["pyramid"] = _ms(t0)
        if self.last is None:
            result, keyframe = self._initialize(frame, timings)
        else:
            with self.map.lock:
                result, keyframe = self._track(frame, timings)
        timings["track"] = _ms(t0)
        if result.quality == "lost":
            self._on_lost()  # outside the map lock: a reset joins the mapping thread
        if result.has_pose and not result.new_segment:
            t1 = time.perf_counter()
            self._map_step(frame, keyframe)
            timings["mapping"] = _ms(t1)
        result.timings = timings
        result.keyframe = keyframe
        return result

    def _initialize(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        t0 = time.perf_counter()
        init = self.initializer
        outcome = init.add(frame) if init.ref is not None else "restart"
        if outcome == "restart":
            init.set_reference(frame)
        timings["init"] = _ms(t0)
        if not isinstance(outcome, InitialMap):
            return FrameResult(frame.t, None, "initializing"), False
        self._build_initial_map(init.ref, frame, outcome)
        ids = frame.feat_point
        _, H, sigma, _ = self._optimize(frame, ids, frame.feat_px, frame.feat_level)
        cov = pose_covariance(H, sigma, frame.T_w_c)
        n = len(ids)
        return FrameResult(frame.t, frame.T_w_c, "good", cov, n, n, n, new_segment=True), True

    def _build_initial_map(self, ref: Frame, cur: Frame, init: InitialMap) -> None:
        """Two keyframes and converged points from the two-view geometry."""
        pts = self.map.points
        ref.T_c_w = np.eye(4)
        cur.T_c_w = init.T_cur_ref.copy()
        n = len(init.depth)
        level = np.zeros(n, dtype=np.int64)
        with self.map.lock:
            slot = self.map.add_keyframe(ref)
            rho = 1.0 / init.depth
            px_angle = self.mapper.px_angle
            sigma = np.array([inverse_depth_sigma(init.T_cur_ref, init.f_ref[i], init.depth[i],
                                                  px_angle) for i in range(n)])
            # no more uncertain than a new candidate's prior (points with little parallax)
            sigma = np.minimum(sigma, self.config.seed_sigma_ratio * np.median(rho))
            ids = pts.add(slot, init.px_ref[:, 0], init.px_ref[:, 1], level, init.f_ref, rho,
                          sigma, np.full(n, 2.0 * rho.max()), self.config.seed_a,
                          self.config.seed_b, np.eye(4))
            done = converged(rho, sigma, pts.pos_w[ids], np.zeros(3), cur.position,
                             self.config.convergence_L)
            pts.status[ids[done]] = CONVERGED
            pts.n_updates[ids[~done]] = self.config.candidate_min_updates
            ref.set_features(ids, init.px_ref, level)
            self.map.obs.add(slot, ids, init.px_ref, level)
            cur.set_features(ids, init.px_cur, level.copy())
            self.map.add_keyframe(cur)
        self.last = cur
        self.motion = np.eye(4)
        self.frames_since_kf = 0
        self.kf_visible = n
        cur.n_visible = n

    def _track(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        cfg = self.config
        last = self.last
        motion = self.motion if cfg.constant_velocity else np.eye(4)
        frame.T_c_w = motion @ last.T_c_w
        t0 = time.perf_counter()
        self._align(frame, last)
        timings["align"] = _ms(t0)
        if cfg.track_candidates or cfg.track_search_fallback:
            t0 = time.perf_counter()
            frame.corners(cfg.fast_threshold, cfg.track_search_min_level)  # epipolar searches
            timings["corners"] = _ms(t0)
        t0 = time.perf_counter()
        ids, uv, levels, n_visible, n_attempts, attempted = self._reproject(frame)
        timings["reproject"] = _ms(t0)
        n_matches = len(ids)
        inlier = np.zeros(n_matches, dtype=bool)
        if n_matches >= MIN_POSE_MATCHES:
            t0 = time.perf_counter()
            T, H, sigma, err = self._optimize(frame, ids, uv, levels)
            inlier = err * np.sqrt(self.camera.fx * self.camera.fy) < cfg.reprojection_inlier_px
            timings["pose"] = _ms(t0)
        # a match counts once it survives the pose refinement
        quality = classify(int(inlier.sum()), n_attempts, cfg)
        if inlier.sum() < MIN_POSE_MATCHES:
            quality = "bad"
        result = FrameResult(frame.t, None, quality, n_matches=n_matches, n_attempts=n_attempts,
                             n_inliers=int(inlier.sum()))
        if quality == "bad":
            if self.lost.update(quality):
                result.quality = "lost"
            return result, False
        self.lost.update(quality)
        frame.T_c_w = orthonormalized(T)
        frame.set_features(ids[inlier], uv[inlier], levels[inlier])
        frame.n_visible = n_visible
        pts = self.map.points
        pts.n_found[ids[inlier]] += 1
        missed = np.setdiff1d(attempted, ids)
        pts.n_missed[missed] += 1
        # points that keep failing (occluded, badly placed, moving) leave the map
        hopeless = (pts.n_missed[missed] > cfg.point_max_missed) & (
            pts.n_missed[missed] > 2 * pts.n_found[missed])
        pts.delete(missed[hopeless])
        self.motion = frame.T_c_w @ inv_se3(last.T_c_w)
        self.last = frame
        self.frames_since_kf += 1
        n_seen = int(inlier.sum()) if cfg.kf_count_inliers else n_visible
        keyframe = quality == "good" and self._need_keyframe(n_seen)
        if keyframe:
            self.frames_since_kf = 0
            self.kf_visible = n_seen
        result.T_w_c = frame.T_w_c
        result.covariance = pose_covariance(H, sigma, result.T_w_c)
        return result, keyframe

    def _need_keyframe(self, n_seen: int) -> bool:
        """Keyframe policy of 6.6: enough frames and points lost, or too many points lost."""
        cfg = self.config
        if n_seen < (1.0 - cfg.lost_points_ratio) * self.kf_visible:
            return True
        # the thesis policy is relative to the last keyframe; a floor keeps a sparse map
        # (a keyframe taken where little was visible) from never growing again
        return self.frames_since_kf >= cfg.kf_min_frames and (
            n_seen < cfg.kf_points_ratio * self.kf_visible or n_seen < cfg.kf_min_points)

    def _on_lost(self) -> None:
        """Lost after consecutive bad frames: the seam for relocalisation (6.9); for now a new
        map is initialised when the config allows it."""
        if self.config.reinit_when_lost:
            self._reset()

    # ------------------------------------------------------------------ stages
    def _align(self, frame: Frame, last: Frame) -> None:
        """Sparse image alignment of frame to the last frame (its matched points)."""
        pts = self.map.points
        alive = (pts.status[last.feat_point] == CANDIDATE) | (
            pts.status[last.feat_point] == CONVERGED)
        if alive.sum() < MIN_POSE_MATCHES:
            return
        ids, px = last.feat_point[alive], last.feat_px[alive]
        X = pts.pos_w[ids] @ last.T_c_w[:3, :3].T + last.T_c_w[:3, 3]
        depth = np.linalg.norm(X, axis=1)
        xyz = self.camera.unproject(px) * depth[:, None]
        T_cur_last = frame.T_c_w @ inv_se3(last.T_c_w)
        cfg = self.config
        T_cur_last = sparse_align.align(self.camera.params, last.pyr, frame.pyr, px, xyz,
                                        T_cur_last, cfg.align_max_level, cfg.align_min_level,
                                        cfg.align_iterations)
        frame.T_c_w = T_cur_last @ last.T_c_w

    def _reproject(self, frame: Frame):
        cfg = self.config
        pts = self.map.points
        usable = pts.status == CONVERGED
        if cfg.track_candidates:
            usable |= (pts.status == CANDIDATE) & (pts.n_updates >= cfg.candidate_min_updates)
        idx = np.flatnonzero(usable)
        search = pts.status[idx] == CANDIDATE
        return self.reprojector.run(self.camera.params, frame, pts, self.map.obs, idx, search,
                                    self.map.kf_pyr, self.map.kf_T_c_w, cfg)

    def _optimize(self, frame: Frame, ids: np.ndarray, uv: np.ndarray, levels: np.ndarray):
        """Pose refinement from matches; returns (T_c_w, H, sigma, per-match error)."""
        f = self.camera.unproject(uv)
        obs = np.ascontiguousarray(f[:, :2] / f[:, 2:])
        focal = float(np.sqrt(self.camera.fx * self.camera.fy))
        pts = self.map.points
        whiten = depth_whitening(frame.T_c_w, self.map.kf_T_c_w, pts.host[ids], pts.f[ids],
                                 pts.rho[ids], pts.sigma[ids], 1.0 / focal)
        return optimize_pose(np.ascontiguousarray(pts.pos_w[ids]), obs,
                             np.ascontiguousarray(levels, dtype=np.int64), whiten, frame.T_c_w,
                             self.config.pose_iterations, 0.5 / focal)


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
