"""The SDVL tracker (thesis 6.1): frames in, world-from-camera poses out.

Tracking per frame (6.7): constant-velocity prior, sparse image alignment to the last frame,
grid-limited matching of map points, Tukey Gauss-Newton pose, quality (6.10). Mapping (6.6)
runs after each frame (sequential, reproducible) or in its own thread with a bounded backlog:
no tracked frame is dropped from mapping; tracking waits for room instead (a live service
skips frames meanwhile), and a frame tracked while frames wait for mapping is not rated good.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from calib.camera import CameraModel
from sdvl.errors import InputError
from vo import bundle_adjustment, outlier_rejection, sparse_align
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
from vo.se3 import exp_se3, inv_se3, orthonormalized

MIN_POSE_MATCHES = 6
# a local BA in the mapping thread waits at most this long (s) per solver step while a frame
# is tracked: its Python code would otherwise take the GIL from tracking between numba calls
BA_PAUSE_MAX_S = 0.05


class MappingBacklog:
    """Tracked frames waiting for their mapping step, oldest first, and the one being mapped
    (by the mapping thread, or by the caller with stepped mapping). It holds `size` frames:
    tracking starts a frame only while there is room."""

    def __init__(self, size: int):
        self.size = size
        self._items: deque = deque()
        self._busy = False
        self._cond = threading.Condition()

    def __len__(self) -> int:
        """Frames tracked and not mapped yet (waiting or being mapped)."""
        with self._cond:
            return self._unmapped()

    def _unmapped(self) -> int:
        return len(self._items) + int(self._busy)

    def waiting(self) -> int:
        """Frames waiting, not counting the one being mapped."""
        with self._cond:
            return len(self._items)

    def has_room(self) -> bool:
        """True while fewer than `size` frames are unmapped."""
        return len(self) < self.size

    def wait_for_room(self, timeout: float | None = None) -> bool:
        """Block until has_room (at most timeout seconds); whether it has."""
        with self._cond:
            return self._cond.wait_for(lambda: self._unmapped() < self.size, timeout)

    def put(self, item) -> None:
        """Append an item (None stops the mapping thread)."""
        with self._cond:
            self._items.append(item)
            self._cond.notify_all()

    def take(self):
        """The oldest item (waiting for one), marked as being mapped until done()."""
        with self._cond:
            self._cond.wait_for(lambda: self._items)
            self._busy = True
            return self._items.popleft()

    def done(self) -> None:
        """The item taken last is mapped."""
        with self._cond:
            self._busy = False
            self._cond.notify_all()


class Tracker:
    """Monocular SDVL tracker for one camera."""

    def __init__(self, camera: CameraModel, config: TrackerConfig | None = None,
                 threaded: bool = False, stepped_mapping: bool = False):
        """`threaded`: mapping in its own thread; `stepped_mapping` (a test hook, without
        `threaded`): mapping as in threaded mode, but only when the caller runs it
        (map_waiting), so a slow mapping thread can be emulated deterministically."""
        self.camera = camera
        self.config = config or TrackerConfig()
        self.threaded = threaded
        self.stepped_mapping = stepped_mapping and not threaded
        self._mapping_error: Exception | None = None
        self._frame_id = 0
        self.backlog: MappingBacklog | None = None
        self._thread: threading.Thread | None = None
        self._idle = threading.Event()  # clear while a frame is being tracked
        self._idle.set()
        self.reprojector = Reprojector(camera, self.config.grid_cell, self.config.seed)
        self._reset()

    # ------------------------------------------------------------------ lifecycle
    def _reset(self) -> None:
        """Forget the map and start initialising again."""
        self._stop_thread()
        cfg = self.config
        self.map = Map(self.camera.width, self.camera.height, cfg.pyramid_levels,
                       cfg.max_keyframes)
        self.map.points.newest_frame = self._frame_id - 1
        self.mapper = Mapper(self.camera, cfg, self.map)
        self.mapper.after_ba = self._follow_ba
        if self.threaded or self.stepped_mapping:
            self.backlog = MappingBacklog(cfg.mapping_queue_size)
            self.mapper.ba_allowed = lambda: self.backlog.waiting() == 0
        if self.threaded:
            self.mapper.ba_pause = lambda: self._idle.wait(BA_PAUSE_MAX_S)
        self.initializer = Initializer(self.camera, cfg)
        self.posed_ref: Frame | None = None  # the initialiser reference poses were given from
        self.last: Frame | None = None
        self.motion = np.eye(4)
        self.lost = LostCounter(cfg)
        self.is_lost = False
        self.lost_init: Initializer | None = None  # a new map, built while relocalising
        self.view_since: int | None = None  # lost, and the view usable since this frame id
        self.frames_since_kf = 0
        self.kf_visible: int | None = None  # points seen at the last keyframe
        if self.threaded:
            self._thread = threading.Thread(target=self._mapping_loop, name="sdvl-mapping",
                                            daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop the mapping thread (if any)."""
        self._stop_thread()

    def _stop_thread(self) -> None:
        if self._thread is not None:
            self.backlog.put(None)
            self._thread.join()
        self._thread = None

    def _mapping_loop(self) -> None:
        backlog = self.backlog
        while True:
            item = backlog.take()
            if item is None:
                return
            try:
                if self._mapping_error is None:  # else drain: tracking must not wait
                    self.mapper.step(*item)
            except Exception as exc:  # re-raised in the tracking thread by process()
                self._mapping_error = exc
            finally:
                backlog.done()

    def wait_for_mapping(self, timeout: float | None = None) -> bool:
        """Wait (threaded mapping) until the mapping backlog has room for another frame;
        False on timeout. A service calls this before taking the newest frame, so a slow
        mapper makes it skip whole frames instead of tracking against a stale map; process()
        waits too."""
        if self.threaded:
            return self.backlog.wait_for_room(timeout)
        return self.backlog is None or self.backlog.has_room()

    def map_waiting(self, n: int = 1) -> int:
        """Stepped mapping: run the mapping steps of up to n waiting frames, oldest first;
        how many ran."""
        done = 0
        while done < n and self.backlog.waiting():
            frame, keyframe = self.backlog.take()
            try:
                self.mapper.step(frame, keyframe)
            finally:
                self.backlog.done()
            done += 1
        return done

    def _follow_ba(self, moved: dict[int, tuple[np.ndarray, np.ndarray]]) -> None:
        """A BA moved keyframes (the mapping thread calls this with the map lock held, so
        between two frames): the last frame, tracked against the map before, moves along
        with them; it is the next frame's prior and alignment reference (threaded, a stale
        one gave kitti00 2.9 m). A keyframe's pose is the map's: the BA set it."""
        last = self.last
        if last is not None and not last.is_keyframe:
            last.T_c_w = bundle_adjustment.follow(last.T_c_w, last.feat_point, self.map, moved)

    def _map_step(self, frame: Frame, keyframe: bool) -> None:
        if self.backlog is None:
            self.mapper.step(frame, keyframe)
        else:
            self.backlog.put((frame, keyframe))  # never dropped: process() waits for room

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
        if self.stepped_mapping:
            self.map_waiting(len(self.backlog) - self.backlog.size + 1)
        elif self.threaded:
            self.backlog.wait_for_room()
        self._idle.clear()  # a BA in the mapping thread waits until the frame is tracked
        try:
            return self._process(image, float(t))
        finally:
            self._idle.set()

    def _process(self, image: np.ndarray, t: float) -> FrameResult:
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        unmapped = 0 if self.backlog is None else len(self.backlog)
        frame = Frame(self._frame_id, float(t), image, self.camera, self.config.pyramid_levels)
        self._frame_id += 1
        self.map.points.newest_frame = frame.id
        timings["pyramid"] = _ms(t0)
        if self.last is None:
            result, keyframe = self._initialize(frame, timings)
        elif self.is_lost:
            with self.map.lock:
                result, keyframe = self._relocalize(frame, timings), False
            if result.quality == "lost":
                result, keyframe = self._initialize_while_lost(frame, timings, result)
        else:
            with self.map.lock:
                result, keyframe = self._track(frame, timings)
        timings["track"] = _ms(t0)
        if result.quality == "good" and unmapped > self.config.mapping_lag_good:
            result.quality = "insufficient"  # the map lags: its pose may be off
        self._idle.set()  # tracked: a BA may go on
        if result.quality == "lost":
            self._on_lost()  # outside the map lock: a reset joins the mapping thread
        # mapping follows frames tracked against the map (a new map's frames are in it
        # already; poses before the map have none)
        if result.has_pose and self.last is frame and not (result.new_segment
                                                            or frame.is_keyframe):
            t1 = time.perf_counter()
            self._map_step(frame, keyframe)
            timings["mapping"] = _ms(t1)
        result.timings = timings
        result.keyframe = keyframe
        return result

    def _initialize(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        outcome = _init_step(self.initializer, frame, timings)
        if not isinstance(outcome, InitialMap):
            return self._pose_before_map(frame, outcome == "restart"), False
        result = self._start_map(self.initializer.ref, frame, outcome)
        # the map's world is the reference camera, in which the poses so far were given
        result.new_segment = self.posed_ref is not self.initializer.ref
        return result, True

    def _pose_before_map(self, frame: Frame, is_reference: bool) -> FrameResult:
        """Before the map exists, the pose relative to the initialiser's reference (the future
        map's world frame) while the camera is at rest: the rotation that explains the tracks
        with the camera still at the reference's position (a translation too small to see;
        its covariance says how small). Only while the tracks have hardly moved at all: a
        sideways move over a distant flat scene shifts them like a turn does, so a rotation fit
        would hide it (survey-down: 0.32 m in 23 frames at a fixed position). The reference
        itself gets no pose: the initialiser may still replace it, and each posed reference
        would be a new map segment. Quality insufficient: no keyframe, no map."""
        init = self.initializer
        found = None if is_reference or not init.at_rest() else init.rotation_only()
        if found is None:
            return FrameResult(frame.t, None, "initializing")
        R_cur_ref, rms = found
        T_w_c = np.eye(4)
        T_w_c[:3, :3] = R_cur_ref.T
        new_segment = self.posed_ref is not init.ref
        self.posed_ref = init.ref
        n = len(init.px_ref)
        cov = rotation_only_covariance(self.camera, init.px_ref, R_cur_ref, rms,
                                       self.config.init_ransac_px)
        return FrameResult(frame.t, T_w_c, "insufficient", cov, n, n, n,
                           new_segment=new_segment)

    def _initialize_while_lost(self, frame: Frame, timings: dict[str, float],
                               lost: FrameResult) -> tuple[FrameResult, bool]:
        """While relocalising, a new map is initialised on the side; it replaces the old map
        once relocalisation has failed for reinit_after_lost_frames frames since the view
        became usable (the initialiser could first track features into a frame: a covered
        lens does not count)."""
        init = self.lost_init
        if init is None:
            return lost, False
        outcome = _init_step(init, frame, timings)
        if outcome != "restart" and self.view_since is None:
            self.view_since = frame.id
        if not isinstance(outcome, InitialMap) or (
                frame.id - self.view_since < self.config.reinit_after_lost_frames):
            return lost, False
        self._reset()
        return self._start_map(init.ref, frame, outcome), True

    def _start_map(self, ref: Frame, frame: Frame, outcome: InitialMap) -> FrameResult:
        """A new map from the initialiser's two views; frame's result (a new segment)."""
        self._build_initial_map(ref, frame, outcome)
        ids = frame.feat_point
        _, H, sigma, _ = self._optimize(frame, ids, frame.feat_px, frame.feat_level)
        cov = pose_covariance(H, sigma, frame.T_w_c)
        n = len(ids)
        return FrameResult(frame.t, frame.T_w_c, "good", cov, n, n, n, new_segment=True)

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
        # the first tracked frame sets it: the initial map's count (all LK tracks) is not
        # comparable with a tracked frame's (at most one match per grid cell)
        self.kf_visible = None
        cur.n_visible = n

    def _track(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        cfg = self.config
        last = self.last
        motion = self.motion if cfg.constant_velocity else np.eye(4)
        frame.T_c_w = motion @ last.T_c_w
        t0 = time.perf_counter()
        self._align(frame, last, last.feat_point, last.feat_px)
        timings["align"] = _ms(t0)
        m = self._match(frame, timings)
        quality = self._quality(m)
        result = FrameResult(frame.t, None, quality, n_matches=len(m.ids),
                             n_attempts=m.n_attempts, n_inliers=int(m.inlier.sum()),
                             n_hypotheses=m.n_hypotheses)
        if quality == "bad":
            if self.lost.update(quality):
                result.quality = "lost"
            return result, False
        self.lost.update(quality)
        self._accept(frame, m)
        self.motion = frame.T_c_w @ inv_se3(last.T_c_w)
        self.last = frame
        n_seen = int(m.inlier.sum()) if cfg.kf_count_inliers else m.n_visible
        keyframe = self._keyframe_due(n_seen, quality == "good")
        result.T_w_c = frame.T_w_c
        result.covariance = pose_covariance(m.H, m.sigma, result.T_w_c)
        return result, keyframe

    def _match(self, frame: Frame, timings: dict[str, float]) -> _Matches:
        """Map points matched in frame (pose prior set) and the pose refined from them."""
        cfg = self.config
        if cfg.track_candidates or cfg.track_search_fallback or cfg.matcher == "orb":
            t0 = time.perf_counter()
            frame.corners(cfg.fast_threshold, cfg.track_corner_level)  # searches among corners
            timings["corners"] = _ms(t0)
        t0 = time.perf_counter()
        ids, uv, levels, n_visible, n_attempts, attempted = self._reproject(frame)
        timings["reproject"] = _ms(t0)
        m = _Matches(ids, uv, levels, n_visible, n_attempts, attempted,
                     np.zeros(len(ids), dtype=bool), frame.T_c_w, None, 0.0)
        if len(ids) < MIN_POSE_MATCHES:
            return m
        t0 = time.perf_counter()
        focal = np.sqrt(self.camera.fx * self.camera.fy)
        use = np.ones(len(ids), dtype=bool)
        if cfg.outlier_rejection and len(ids) > outlier_rejection.SUBSET:
            use, m.n_hypotheses = self._reject_outliers(frame, ids, uv, levels)
            timings["ransac"] = _ms(t0)
        if use.sum() >= MIN_POSE_MATCHES:
            T, H, sigma, err = self._optimize(frame, ids[use], uv[use], levels[use])
            if cfg.outlier_rejection:
                # rescue: outliers within a wider threshold of the inlier pose join them
                frame.T_c_w, prior = T, frame.T_c_w
                use = self._errors(frame, ids, uv) * focal < cfg.ransac_rescue_px
                frame.T_c_w = prior
                T, H, sigma, err = self._optimize(frame, ids[use], uv[use], levels[use])
            m.T, m.H, m.sigma = T, H, sigma
            m.inlier[use] = err * focal < cfg.reprojection_inlier_px
        timings["pose"] = _ms(t0)
        return m

    def _errors(self, frame: Frame, ids: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Reprojection errors (normalised plane) of matches at frame's pose."""
        f = self.camera.unproject(uv)
        obs = np.ascontiguousarray(f[:, :2] / f[:, 2:])
        pos = np.ascontiguousarray(self.map.points.pos_w[ids])
        return np.sqrt(outlier_rejection.squared_errors(pos, obs, frame.T_c_w))

    def _reject_outliers(self, frame: Frame, ids: np.ndarray, uv: np.ndarray,
                         levels: np.ndarray) -> tuple[np.ndarray, int]:
        """RANSAC inliers (6.8) among the matches, hypotheses from frame's prior pose; and
        how many hypotheses were fitted."""
        cfg = self.config
        f = self.camera.unproject(uv)
        obs = np.ascontiguousarray(f[:, :2] / f[:, 2:])
        scale = 1.0 / 2.0 ** levels
        subsets = outlier_rejection.random_subsets(len(ids), cfg.ransac_max_hypotheses,
                                                   cfg.seed + frame.id)
        focal = np.sqrt(self.camera.fx * self.camera.fy)
        inlier, tried = outlier_rejection.ransac(
            np.ascontiguousarray(self.map.points.pos_w[ids]), obs, scale, frame.T_c_w, subsets,
            cfg.ransac_threshold_px / focal, cfg.ransac_probability)
        return inlier, int(tried)

    def _quality(self, m: _Matches) -> str:
        """Quality of 6.10; a match counts once it survives the pose refinement."""
        n_inliers = int(m.inlier.sum())
        if n_inliers < MIN_POSE_MATCHES:
            return "bad"
        return classify(n_inliers, m.n_attempts, self.config)

    def _accept(self, frame: Frame, m: _Matches) -> None:
        """Give frame its refined pose and matches; update the points' found/missed counts."""
        cfg = self.config
        ids, inlier = m.ids, m.inlier
        frame.T_c_w = orthonormalized(m.T)
        frame.pose_info = m.H
        frame.set_features(ids[inlier], m.uv[inlier], m.levels[inlier])
        frame.n_visible = m.n_visible
        pts = self.map.points
        pts.n_found[ids[inlier]] += 1
        if cfg.outlier_rejection:
            self._forget_rejected(ids, inlier)
        missed = np.setdiff1d(m.attempted, ids)
        pts.n_missed[missed] += 1
        # points that keep failing (occluded, badly placed, moving) leave the map
        hopeless = (pts.n_missed[missed] > cfg.point_max_missed) & (
            pts.n_missed[missed] > 2 * pts.n_found[missed])
        pts.delete(missed[hopeless])

    def _forget_rejected(self, ids: np.ndarray, inlier: np.ndarray) -> None:
        """Map hygiene of outlier rejection (6.8): matched points the pose rejects in
        point_max_rejected tracked frames in a row have moved or were badly placed; they leave
        the map instead of being matched (and rejected) again in every frame."""
        pts = self.map.points
        pts.n_rejected[ids[inlier]] = 0
        rejected = ids[~inlier]
        pts.n_rejected[rejected] += 1
        pts.delete(rejected[pts.n_rejected[rejected] >= self.config.point_max_rejected])

    def _keyframe_due(self, n_seen: int, good: bool) -> bool:
        """Count a tracked frame that sees n_seen map points; True when it becomes a keyframe
        (only a good frame can). The points "seen when the keyframe was made" (6.6) include
        its new candidates, which tracking uses once the mapper has added them and updated
        them candidate_min_updates times: until then the reference is the most points seen
        (else a keyframe taken with few points keeps the reference low and the next one comes
        too late: kitti00 turned for 20 frames without one and lost the map). The window
        counts the frames mapped since the keyframe, not those tracked: a mapping thread that
        lags updates the candidates later. It applies to the count of projected points only:
        with inlier counts (the default) it took keyframes too often on vamr (ATE 0.0017 ->
        0.030 m)."""
        self.frames_since_kf += 1
        if self.kf_visible is None:
            self.kf_visible = n_seen
        elif (not self.config.kf_count_inliers
              and self.mapper.frames_since_keyframe <= self.config.candidate_min_updates):
            self.kf_visible = max(self.kf_visible, n_seen)
        if not (good and self._need_keyframe(n_seen)):
            return False
        self.frames_since_kf = 0
        self.kf_visible = n_seen
        return True

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
        """Tracking is lost: relocalise (6.9) against the map from now on (building a new
        map on the side when re-initialisation is allowed), or start a new map at once when
        relocalisation is off."""
        cfg = self.config
        if self.is_lost:
            return
        if cfg.relocalize and self.map.keyframes:
            self.is_lost = True
            self.view_since = None
            self.lost_init = Initializer(self.camera, cfg) if cfg.reinit_when_lost else None
        elif cfg.reinit_when_lost:
            self._reset()

    def _relocalize(self, frame: Frame, timings: dict[str, float]) -> FrameResult:
        """Try the keyframes newest first: direct alignment to the keyframe, then matching map
        points; the first with enough inliers gives the pose and tracking resumes from it."""
        cfg = self.config
        t0 = time.perf_counter()
        slots = sorted(self.map.keyframes, key=lambda s: -self.map.keyframes[s].id)
        if cfg.reloc_max_keyframes > 0:
            slots = slots[:cfg.reloc_max_keyframes]
        for slot in slots:
            kf = self.map.keyframes[slot]
            if not self._align_to_keyframe(frame, kf) < cfg.reloc_max_residual_ratio:
                continue
            m = self._match(frame, {})
            if m.inlier.sum() >= cfg.reloc_min_matches and self._quality(m) != "bad":
                cov = pose_covariance(m.H, m.sigma, orthonormalized(m.T))
                if _rotation_std_deg(cov) <= cfg.reloc_max_rotation_std_deg:
                    break
        else:
            timings["relocalize"] = _ms(t0)
            return FrameResult(frame.t, None, "lost")
        timings["relocalize"] = _ms(t0)
        self._accept(frame, m)
        self.is_lost = False
        self.lost_init = None
        self.lost = LostCounter(cfg)
        self.motion = np.eye(4)
        self.last = frame
        return FrameResult(frame.t, frame.T_w_c, self._quality(m), cov, len(m.ids), m.n_attempts,
                           int(m.inlier.sum()), new_segment=True, n_hypotheses=m.n_hypotheses)

    def _align_to_keyframe(self, frame: Frame, kf: Frame) -> float:
        """Frame's pose by direct alignment to keyframe kf from the best of the shifted
        priors; returns the residual ratio of that alignment."""
        ids, px = self.map.observed_by(kf.slot)
        X = self.map.points.pos_w[ids] @ kf.T_c_w[:3, :3].T + kf.T_c_w[:3, 3]
        depth = float(np.median(X[:, 2])) if len(X) else 1.0
        best, best_T = np.inf, kf.T_c_w
        for prior in shifted_priors(kf, frame, self.camera, self.config.reloc_shift_level,
                                    depth):
            frame.T_c_w = prior
            ratio = self._align(frame, kf, ids, px, measure=True)
            if ratio < best:
                best, best_T = ratio, frame.T_c_w
        frame.T_c_w = best_T
        return best

    # ------------------------------------------------------------------ stages
    def _align(self, frame: Frame, last: Frame, ids: np.ndarray, px: np.ndarray,
               measure: bool = False) -> float:
        """Sparse image alignment of frame to an earlier frame through the points `ids` it
        saw at pixels `px`; with `measure`, returns how badly the patches fit afterwards
        (sparse_align.residual_ratio, at the finest level aligned; inf when alignment was
        impossible)."""
        pts = self.map.points
        alive = (pts.status[ids] == CANDIDATE) | (pts.status[ids] == CONVERGED)
        if alive.sum() < MIN_POSE_MATCHES:
            return np.inf
        ids, px = ids[alive], px[alive]
        X = pts.pos_w[ids] @ last.T_c_w[:3, :3].T + last.T_c_w[:3, 3]
        depth = np.linalg.norm(X, axis=1)
        xyz = self.camera.unproject(px) * depth[:, None]
        T_cur_last = frame.T_c_w @ inv_se3(last.T_c_w)
        cfg = self.config
        T_cur_last = sparse_align.align(self.camera.params, last.pyr, frame.pyr, px, xyz,
                                        T_cur_last, cfg.align_max_level, cfg.align_min_level,
                                        cfg.align_iterations, cfg.align_robust)
        frame.T_c_w = T_cur_last @ last.T_c_w
        if not measure:
            return np.nan
        return sparse_align.residual_ratio(self.camera.params, last.pyr, frame.pyr, px, xyz,
                                           T_cur_last, cfg.align_min_level)

    def _reproject(self, frame: Frame):
        cfg = self.config
        pts = self.map.points
        usable = pts.status == CONVERGED
        if cfg.track_candidates:
            usable |= (pts.status == CANDIDATE) & (pts.n_updates >= cfg.candidate_min_updates)
        idx = np.flatnonzero(usable)
        search = pts.status[idx] == CANDIDATE
        return self.reprojector.run(self.camera.params, frame, pts, self.map.obs, idx, search,
                                    self.map.kf_pyr, self.map.kf_T_c_w, cfg,
                                    self.map.describe_points)

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


def rotation_only_covariance(camera: CameraModel, px_ref: np.ndarray, R_cur_ref: np.ndarray,
                             rms_px: float, threshold_px: float) -> np.ndarray:
    """Covariance of a pose from a rotation-only fit (translation, rotation; world = reference
    camera, scene depth ~1 as the map will be scaled): a sideways move of d shifts the tracks by
    d * focal px, a move along the axis by d * focal * r (r = normalised radius), so an unseen
    move is below threshold_px over that; the rotation is known to rms_px / focal / sqrt(n)."""
    focal = float(np.sqrt(camera.fx * camera.fy))
    f = camera.unproject(px_ref)
    radius = float(np.median(np.linalg.norm(f[:, :2] / f[:, 2:], axis=1)))
    std_t = threshold_px / focal
    var_c = np.array([std_t, std_t, std_t / max(radius, 0.1)]) ** 2
    cov = np.zeros((6, 6))
    cov[:3, :3] = R_cur_ref.T @ np.diag(var_c) @ R_cur_ref
    cov[3:, 3:] = np.eye(3) * (max(rms_px, 0.1) / focal) ** 2 / len(px_ref)
    return cov


def shifted_priors(kf: Frame, frame: Frame, camera: CameraModel, level: int,
                   depth: float) -> list[np.ndarray]:
    """T_c_w priors for frame from the keyframe's pose and the image shift that phase
    correlation finds between the two images at pyramid `level` (the view may be far outside
    the basin of direct alignment): the keyframe turned, and the keyframe moved sideways
    (scene at `depth`), so that its image moves by that shift."""
    a = np.float32(kf.pyr.images[level])
    b = np.float32(frame.pyr.images[level])
    (du, dv), _ = cv2.phaseCorrelate(a - a.mean(), b - b.mean())
    # the correlation is circular: a shift by more than half the image (a view that overlaps
    # the keyframe by less than half) shows up wrapped, so its unwrapped twin is tried too
    priors = []
    for su in (du, du - np.sign(du) * a.shape[1]):
        for sv in (dv, dv - np.sign(dv) * a.shape[0]):
            priors += _shift_priors(kf.T_c_w, camera, su * 2.0 ** level, sv * 2.0 ** level,
                                    depth)
    return priors


def _shift_priors(T_c_w: np.ndarray, camera: CameraModel, du: float, dv: float,
                  depth: float) -> list[np.ndarray]:
    """The pose T_c_w turned, and moved sideways (scene at `depth`), so that its image content
    shifts by (du, dv) pixels."""
    # content moves by +du when the camera turns by du / f about its y axis, or moves by
    # -du * depth / f along its x axis
    turn = np.array([0.0, 0.0, 0.0, -np.arctan(dv / camera.fy), np.arctan(du / camera.fx), 0.0])
    move = np.eye(4)
    move[:3, 3] = (du * depth / camera.fx, dv * depth / camera.fy, 0.0)
    return [exp_se3(turn) @ T_c_w, move @ T_c_w]


@dataclass
class _Matches:
    """One frame's matched map points and the pose refined from them."""

    ids: np.ndarray
    uv: np.ndarray
    levels: np.ndarray
    n_visible: int
    n_attempts: int
    attempted: np.ndarray
    inlier: np.ndarray
    T: np.ndarray
    H: np.ndarray | None
    sigma: float
    n_hypotheses: int = 0


def _rotation_std_deg(cov: np.ndarray | None) -> float:
    """The largest rotation standard deviation (degrees) of a pose covariance (inf if none)."""
    if cov is None:
        return np.inf
    return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:])[-1], 0.0))))


def _init_step(init: Initializer, frame: Frame, timings: dict[str, float]):
    """Feed frame to an initialiser (restarting it from frame when needed); its outcome."""
    t0 = time.perf_counter()
    outcome = init.add(frame) if init.ref is not None else "restart"
    if outcome == "restart":
        init.set_reference(frame)
    timings["init"] = _ms(t0)
    return outcome


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
