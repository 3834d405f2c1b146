"""Tracking a frame against the map (thesis 6.7): constant-velocity prior, sparse image
alignment to the last frame, map matching and pose refinement, the quality of 6.10 and the
lost state after bad frames in a row (6.9), and the keyframe decision (6.6)."""

from __future__ import annotations

import time
from collections import deque

import numpy as np

from vo.config import TrackerConfig
from vo.frame import Frame
from vo.frame_alignment import align_frame
from vo.keyframe_policy import KeyframePolicy
from vo.map_matching import MapMatcher, Matches
from vo.pose_optimizer import pose_covariance
from vo.quality import LostCounter
from vo.result import FrameResult, PriorUse, Quality, ms_since
from vo.rotation_prior import agrees, relative_prior
from vo.se3 import inv_se3, rotation_angle_deg, scaled_motion

PERIOD_INTERVALS = 31  # the camera's frame period: the median of this many frame intervals
MAX_CARRY = 10  # the last motion carried over at most this many times its own frames


class FrameTracking:
    """Tracks frames one after the other from the last tracked frame of one map."""

    def __init__(self, config: TrackerConfig, matcher: MapMatcher, keyframes: KeyframePolicy):
        self.config = config
        self.matcher = matcher
        self.keyframes = keyframes
        self.last: Frame | None = None  # the last frame with a pose in this map
        # the last frame published, and the motion, its time and turn rate up to it
        self.published: tuple[Frame, np.ndarray, float, float] | None = None
        self.motion = np.eye(4)  # T_c_w of the last frame times the inverse of the one before
        self.motion_s = 0.0  # the time that motion took (0: none yet)
        self.intervals: deque[float] = deque(maxlen=PERIOD_INTERVALS)  # between frames seen
        self.t_seen: float | None = None  # the last frame's time
        self.turn_rate = 0.0  # degrees per second the camera turned in that motion
        self.lost = LostCounter(config)

    def track(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        """Track frame from the last one: its result (quality LOST once too many frames in a
        row were bad) and whether it becomes a keyframe."""
        cfg = self.config
        last = self.last
        t0 = time.perf_counter()
        use = self._align(frame, last)
        timings["align"] = ms_since(t0)
        m = self.matcher.match(frame, timings)
        quality = self.matcher.quality(m)
        if quality == Quality.INSUFFICIENT and last is not self.published[0]:
            quality = Quality.BAD  # after a hold only a good frame is published
        result = FrameResult(frame.t, None, quality, n_matches=len(m.ids),
                             n_attempts=m.n_attempts, n_inliers=m.n_inliers,
                             n_hypotheses=m.n_hypotheses, rotation_prior=use)
        if quality == Quality.BAD:
            self._on_bad(frame, last, m, result)
            return result, False
        self.lost.update(quality)
        self.matcher.accept(frame, m)
        self._moved_to(frame, last)
        self._publish(frame)
        n_seen = m.n_inliers if cfg.kf_count_inliers else m.n_visible
        keyframe = self.keyframes.due(n_seen, quality == Quality.GOOD, frame)
        result.T_w_c = frame.T_w_c
        result.covariance = pose_covariance(m.H, m.sigma, result.T_w_c)
        return result, keyframe

    def _on_bad(self, frame: Frame, last: Frame, m: Matches, result: FrameResult) -> None:
        """A bad frame (its matches m, its result): held, within hold_max_s of the last frame
        published (MapMatcher.held: tracked on from, not published, no step towards lost),
        or a step towards lost; once lost, relocalisation and a new map go on from the last
        frame published, not from held ones."""
        dt = frame.t - self.published[0].t
        if 0.0 <= dt <= self.config.hold_max_s and self.matcher.held(m):
            self.matcher.accept(frame, m, count=False)
            self._moved_to(frame, last)
            result.held = True
        elif self.lost.update(Quality.BAD):
            result.quality = Quality.LOST
            self.last, self.motion, self.motion_s, self.turn_rate = self.published

    def _moved_to(self, frame: Frame, last: Frame) -> None:
        """Frame, its pose accepted, is the last frame: the motion from `last` to it is the
        constant-velocity model's."""
        self.motion = frame.T_c_w @ inv_se3(last.T_c_w)
        dt = frame.t - last.t
        self.motion_s = max(dt, 0.0)
        self.turn_rate = rotation_angle_deg(self.motion[:3, :3]) / dt if dt > 0 else 0.0
        self.last = frame

    def _publish(self, frame: Frame) -> None:
        """Frame, the last one, is published: what tracking goes on from after a hold."""
        self.published = (frame, self.motion, self.motion_s, self.turn_rate)

    def _at_rest(self, frame: Frame) -> None:
        """Frame is the last and published one, with no motion known yet (a new map or a
        relocalised frame)."""
        self.last = frame
        self.motion, self.motion_s = np.eye(4), 0.0
        self.turn_rate = 0.0
        self._publish(frame)

    def _align(self, frame: Frame, last: Frame) -> PriorUse:
        """Sparse image alignment to the last frame from the predicted pose: the constant-
        velocity motion, turned by the rotation prior when there is one; a prior the alignment
        turns away from beyond the gate is refused and the alignment done again without it."""
        cfg = self.config
        predicted = self._carried(frame.t - last.t) @ last.T_c_w
        if self.t_seen is not None and frame.t > self.t_seen:
            self.intervals.append(frame.t - self.t_seen)
        self.t_seen = frame.t
        prior = relative_prior(frame.orientation, last.orientation, last.T_c_w[:3, :3],
                               cfg.rotation_prior_deg)
        if prior is not None:
            frame.T_c_w = _turned_in_place(predicted, prior[0])
            self._align_to(frame, last)
            if agrees(frame.T_c_w[:3, :3], prior[0], cfg.rotation_prior_gate_deg):
                frame.R_prior, frame.prior_info = prior
                return PriorUse.USED
        frame.T_c_w = predicted
        self._align_to(frame, last)
        return PriorUse.NONE if prior is None else PriorUse.REFUSED

    def _carried(self, dt: float) -> np.ndarray:
        """The constant-velocity motion over the dt seconds since the last frame: the last
        motion times the frame periods dt spans over those it spanned (frames the service
        dropped, or a bad frame, in either: a per-frame motion fell 0.36 m short after eight
        dropped frames and tracking took a wrong pose). Whole periods, so a camera's jittery
        stamps (TUM's 25-40 ms at 30 Hz) change nothing."""
        if not self.config.constant_velocity:
            return np.eye(4)
        if not self.intervals or self.motion_s <= 0.0 or dt <= 0.0:
            return self.motion
        period = float(np.median(self.intervals))
        now, before = max(1, round(dt / period)), max(1, round(self.motion_s / period))
        if now == before:
            return self.motion
        return scaled_motion(self.motion, min(now / before, MAX_CARRY))

    def _align_to(self, frame: Frame, last: Frame) -> None:
        align_frame(frame, last, last.feat_point, last.feat_px, self.matcher.map.points,
                    self.matcher.camera, self.config)

    def start(self, frame: Frame, n_visible: int) -> FrameResult:
        """Track on from the second keyframe of a new map (its points `frame.feat_point`):
        its result, a new segment with the covariance of its pose from its matches."""
        self._at_rest(frame)
        self.keyframes.restart()
        frame.n_visible = n_visible
        ids = frame.feat_point
        _, H, sigma, _ = self.matcher.optimize(frame, ids, frame.feat_px, frame.feat_level)
        cov = pose_covariance(H, sigma, frame.T_w_c)
        n = len(ids)
        return FrameResult(frame.t, frame.T_w_c, Quality.GOOD, covariance=cov, n_matches=n,
                           n_attempts=n, n_inliers=n, new_segment=True)

    def resume(self, frame: Frame, m: Matches, cov: np.ndarray, count: bool = True
               ) -> FrameResult:
        """Track on from a relocalised frame (its matches m, pose covariance cov): its result,
        a new segment (the pose may jump) in the same map (relocalized); without `count`, the
        points' found/missed counts are left as they are (a candidate pose, not yet
        believed)."""
        self.matcher.accept(frame, m, count)
        self.lost = LostCounter(self.config)
        self._at_rest(frame)
        return FrameResult(frame.t, frame.T_w_c, self.matcher.quality(m), covariance=cov,
                           n_matches=len(m.ids), n_attempts=m.n_attempts,
                           n_inliers=m.n_inliers, new_segment=True, relocalized=True,
                           n_hypotheses=m.n_hypotheses)

    def save(self) -> tuple:
        """What tracking goes on from (restore puts it back)."""
        kf = self.keyframes
        return (self.last, self.motion, self.motion_s, self.turn_rate, self.lost,
                self.published, kf.frames_since_kf, kf.kf_visible)

    def restore(self, saved: tuple) -> None:
        """Go on from what save returned (a candidate tracked from was not confirmed)."""
        kf = self.keyframes
        (self.last, self.motion, self.motion_s, self.turn_rate, self.lost,
         self.published, kf.frames_since_kf, kf.kf_visible) = saved


def _turned_in_place(T_c_w: np.ndarray, R_c_w: np.ndarray) -> np.ndarray:
    """T_c_w with the rotation R_c_w, the camera's centre kept."""
    out = T_c_w.copy()
    out[:3, :3] = R_c_w
    out[:3, 3] = -R_c_w @ (-T_c_w[:3, :3].T @ T_c_w[:3, 3])
    return out

