"""FusionEstimator: the EKF behind the daemon's Estimator seam (daemon/estimate.py).

Autopilot messages are queued as they arrive (asyncio thread) with their arrival time; each
tracker frame (tracking thread) maps their stamps to our clock, applies everything up to the
frame's capture time in time order (replaying the filter for late ones), fuses the frame and
returns an estimate once scale and heading have converged.

Local frame: NED with the origin at the vehicle's position at the first tracked frame; heading
from the autopilot's attitude (compass), so it agrees with the autopilot's own yaw.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from daemon.config import MountingConfig
from daemon.estimate import VisionEstimate
from daemon.fusion import measurements as m
from daemon.fusion.alignment import AlignmentGate
from daemon.fusion.attitude import AttitudeTrack
from daemon.fusion.clock import ClockMap
from daemon.fusion.config import FusionConfig
from daemon.fusion.output import build_estimate, inflation
from daemon.fusion.sensors import BARO_PRIORITY, IMU_PRIORITY, Attitude, Baro, Imu, Range, parse
from daemon.fusion.source_choice import SourceChoice
from daemon.fusion.state import ANCHOR, LOG_SCALE, POS, NavFilter
from daemon.fusion.timeline import Event, Timeline
from daemon.mounting import body_from_camera
from vo.pose_optimizer import MAD_TO_SIGMA

log = logging.getLogger("sdvl.fusion")
INBOX_LIMIT = 20_000
TRACKED = ("good", "insufficient", "bad")
RANGE_FRESH_S = 0.5  # a rangefinder reading this close to a frame measures its height
MIN_SCENE_POINTS = 20  # matched map points for a median height


@dataclass(frozen=True)
class FrameInput:
    """What the filter uses of a tracker frame."""

    p_w: np.ndarray  # camera position in the tracker's world
    R_w_b: np.ndarray  # body attitude in the tracker's world
    cov: np.ndarray  # 6x6 position (tracker units) and rotation (rad), tracker world frame
    quality: str
    segment: int
    scene_w: np.ndarray | None = None  # matched map points, tracker world (scene.py)


def _frame_input(result: object, R_c_b: np.ndarray, segment: int,
                 position_factor: float = 1.0) -> FrameInput | None:
    """The tracker pose as filter input, its position variances times `position_factor`
    (correlations kept); None when it has no usable pose."""
    if not result.has_pose or result.quality not in TRACKED:
        return None
    T = np.asarray(result.T_w_c, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return None
    cov = np.zeros((6, 6))
    if result.covariance is not None:
        given = np.asarray(result.covariance, dtype=np.float64)
        if given.shape == (6, 6) and np.all(np.isfinite(given)) and np.all(np.diag(given) >= 0):
            cov = 0.5 * (given + given.T)
    stretch = np.diag([np.sqrt(position_factor)] * 3 + [1.0] * 3)
    return FrameInput(T[:3, 3].copy(), T[:3, :3] @ R_c_b, stretch @ cov @ stretch,
                      result.quality, segment, getattr(result, "scene_w", None))


class FusionEstimator:
    """Scale, gravity, heading and velocity for the tracker's poses; see the module doc."""

    def __init__(self, cfg: FusionConfig, mounting: MountingConfig,
                 report: Callable[[str], None] | None = None,
                 now: Callable[[], float] = time.monotonic):
        cfg.check()
        self.cfg = cfg
        self.R_c_b = body_from_camera(mounting).T
        self.now = now
        self.reset_counter = 0
        self.filter = NavFilter(cfg)
        self.gate = AlignmentGate(cfg, report)
        self.attitude = AttitudeTrack(cfg.attitude_timeout_s, cfg.history_s + 2.0)
        self.clock = ClockMap(cfg.clock_offset_window_s)
        self.timeline = Timeline(cfg.history_s)
        self.sources: dict[str, str] = {}  # "imu"/"baro" -> the message type fused
        self._choices: dict[str, SourceChoice] = {}
        self.dropped_stamps = 0
        self._inbox: deque[tuple[float, object]] = deque(maxlen=INBOX_LIMIT)
        self._lock = threading.Lock()
        self._segment = 0
        self._had_segment = False
        self._realigns_seen = 0
        self._origin_t: float | None = None  # capture time of the first estimate sent
        self._last_frame_t = float("-inf")
        self._range: tuple[float, float] | None = None  # (t, distance) of the newest reading
        self._baro: tuple[float, float] | None = None  # (t, altitude) of the newest reading
        optical_axis = self.R_c_b.T[:, 2]  # in body FRD
        self._camera_down = optical_axis[2] >= np.cos(np.radians(cfg.range_max_tilt_deg))

    # --- the Estimator protocol ---------------------------------------------------------------

    def on_autopilot_message(self, msg: object) -> None:
        """Queue a message with its arrival time; the tracking thread fuses it."""
        with self._lock:
            self._inbox.append((self.now(), msg))

    def set_clock_offset(self, offset_s: float | None) -> None:
        """Our monotonic time minus the autopilot's boot time, from TIMESYNC (seconds)."""
        with self._lock:
            self.clock.set_offset(offset_s)

    def on_frame(self, result: object, t_capture: float) -> VisionEstimate | None:
        """Fuse one tracker FrameResult captured at `t_capture` (our monotonic seconds)."""
        self._drain()
        if result.new_segment and self._had_segment:
            self._segment += 1
            self._bump_reset_counter()
        frame = _frame_input(result, self.R_c_b, self._segment, self.cfg.vo_covariance_factor)
        if not np.isfinite(t_capture) or t_capture <= self._last_frame_t:
            return None
        self._last_frame_t = t_capture
        if frame is not None:
            self._had_segment = True
            self.timeline.add(t_capture, "frame", frame)
        f = self.filter
        self.timeline.run(t_capture, f.t, self._apply, f.restore, f.snapshot)
        if f.realigns != self._realigns_seen:
            self._realigns_seen = f.realigns
            self._bump_reset_counter()
        if frame is None or f.t != t_capture or f.segment != frame.segment:
            return None
        if not self.gate.update(f, t_capture):
            return None
        f.published = True
        if f.origin is None:  # a rewind to this frame or before must keep the fix
            self._origin_t = t_capture
            f.fix_origin()
            self.timeline.retake(t_capture, f.snapshot())
        att = self.attitude.at(t_capture)
        return build_estimate(
            f, self.cfg, R_w_b=frame.R_w_b, rot_cov_w=frame.cov[3:, 3:],
            rates=att.rates if att is not None else np.zeros(3), t_capture=t_capture,
            t_source=float(result.t), state=result.quality, reset_counter=self.reset_counter)

    # --- inputs -------------------------------------------------------------------------------

    def _bump_reset_counter(self) -> None:
        self.reset_counter = (self.reset_counter + 1) % 256
        self.gate.restart()
        log.info("fusion: discontinuity, reset_counter %d", self.reset_counter)

    def _drain(self) -> None:
        """Autopilot messages -> attitude track and timeline events on our clock."""
        with self._lock:
            items = list(self._inbox)
            self._inbox.clear()
            for arrival, msg in items:
                self._ingest(arrival, msg)

    def _ingest(self, arrival: float, msg: object) -> None:
        parsed = parse(msg)
        if parsed is None:
            return
        remote, samples = parsed
        t = self.clock.to_local(remote, arrival)
        if t is None:
            self.dropped_stamps += 1
            return
        for sample in samples:
            sample = dataclasses.replace(sample, t=t)
            if isinstance(sample, Attitude):
                self.attitude.add(sample)
                self.timeline.add(t, "attitude", None)  # late ones replay what used it
            elif isinstance(sample, Imu) and self.cfg.use_imu:
                self._add_stream("imu", sample, IMU_PRIORITY)
            elif isinstance(sample, Range) and self.cfg.use_rangefinder:
                self.timeline.add(t, "range", sample)
            elif isinstance(sample, Baro) and self.cfg.use_baro:
                self._add_stream("baro", sample, BARO_PRIORITY)

    def _add_stream(self, kind: str, sample: Imu | Baro, priority: dict[str, int]) -> None:
        """Fuse one stream of a kind: the preferred one that streams steadily (source_choice)."""
        choice = self._choices.setdefault(kind, SourceChoice(kind, priority))
        if choice.offer(sample.source, sample.t):
            self.sources[kind] = sample.source
            self.timeline.add(sample.t, kind, sample)

    # --- the filter ---------------------------------------------------------------------------

    def _apply(self, event: Event) -> None:
        f = self.filter
        if event.kind == "frame":
            self._apply_frame(event.t, event.data)
            return
        if event.kind == "range":
            self._range = (event.t, event.data.distance)
        elif event.kind == "baro":
            self._baro = (event.t, event.data.altitude)
        if f.t is None or event.kind == "attitude":
            return
        self._propagate(event.t)
        if event.kind == "imu":
            f.accel, f.t_accel = event.data.accel, event.t
        elif event.kind == "range":
            att = self.attitude.at(event.t)
            if att is not None:
                m.update_range(f, event.data.distance, att.R_n_b)
        elif event.kind == "baro":
            m.update_baro(f, event.data.altitude)

    def _imu_fresh(self, t: float) -> bool:
        f = self.filter
        return f.accel is not None and t - f.t_accel <= self.cfg.imu_timeout_s

    def _propagate(self, t: float) -> None:
        f = self.filter
        att = self.attitude.at(f.t) if self._imu_fresh(t) else None
        f.predict(t, f.accel if att is not None else None,
                  att.R_n_b if att is not None else None)

    def _apply_frame(self, t: float, frame: FrameInput) -> None:
        self._fuse_frame(t, frame)
        if t == self._origin_t and self.filter.origin is None:
            self.filter.fix_origin()

    def _fuse_frame(self, t: float, frame: FrameInput) -> None:
        f = self.filter
        att = self.attitude.at(t)
        if f.t is None:
            if att is None:
                self.gate.waiting("waiting for the autopilot's ATTITUDE", t)
                return
            f.start(t, self.cfg.start_velocity_std)
        self._propagate(t)
        if f.segment != frame.segment:
            if att is None:
                return
            f.start_segment(frame.p_w, frame.R_w_b, att.R_n_b, *self._scale_prior(t))
            f.segment = frame.segment
            return
        self._climb_scale(t, frame, att)
        self._accel_scale(t, frame, att)
        factor = inflation(self.cfg, frame.quality)
        coarse = (self.cfg.coarse_inflation
                  if np.sqrt(f.P[LOG_SCALE, LOG_SCALE]) > self.cfg.coarse_scale_std else 1.0)
        R_n_b = f.R_nom @ frame.R_w_b
        attitude = (None if att is None
                    else (att.R_n_b, frame.R_w_b, self._attitude_noise(frame.quality)))
        if m.update_vo(f, frame.p_w, frame.cov, R_n_b, factor, self._imu_fresh(t), attitude,
                       coarse):
            if np.linalg.norm(f.x[POS] - f.x[ANCHOR]) > self.cfg.reanchor_distance_m:
                f.reanchor(frame.p_w)
            self._scene_height(t, frame, R_n_b)
        elif f.rejections["vo"] >= self.cfg.reset_after_rejections and att is not None:
            if f.published:
                f.realigns += 1  # the autopilot saw this map: reset_counter must change
            # the same map: its scale holds, only where it puts the camera now is re-anchored
            f.start_segment(frame.p_w, frame.R_w_b, att.R_n_b, f.x[LOG_SCALE],
                            float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE])))
            f.rejections["vo"] = 0
        if f.scale_source == "prior":
            f.forget_scale()

    def _climb_scale(self, t: float, frame: FrameInput, att: object) -> None:
        """Pair the tracker's height with the barometer's; while the filter does not know the
        scale from elsewhere (std above coarse_scale_std, or no IMU) and has not published, take
        it from their fit over the climb when that is surer (climb_scale.py)."""
        f, cfg = self.filter, self.cfg
        if self._baro is None or abs(t - self._baro[0]) > RANGE_FRESH_S or f.published:
            return  # once published the fit is not used: pairing on would grow without bound
        f.climb.add(float((f.R_nom @ (frame.p_w - f.p_w0))[2]), *self._baro)
        std = float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]))
        if att is None or f.published or (std <= cfg.coarse_scale_std and self._imu_fresh(t)):
            return
        fit = f.climb.fit(cfg.climb_scale_min_m, cfg.baro_std_m)
        if fit is not None:  # the map's own scale wanders over the climb (its walk, halved)
            fit = (fit[0], float(np.hypot(fit[1], 0.5 * cfg.scale_walk_climb_per_sqrt_m
                                          * np.sqrt(f.climb.climb_m(fit[0])))))
        if fit is not None and fit[1] < std:
            log.info("fusion: scale %.3g m/unit from the climb (+-%.1f%%)", np.exp(fit[0]),
                     100 * fit[1])
            f.rescale(frame.p_w, att.R_n_b, *fit)

    def _accel_scale(self, t: float, frame: FrameInput, att: object) -> None:
        """Pair the map's position with the IMU's double integral; until the filter publishes,
        take the scale from their linear fit (accel_scale.py) once that is good to
        coarse_scale_std: when it is surer than a scale not given with the map (the wide prior,
        or an earlier fit), or more than 3 sigma away from the filter's (its linearised scale
        has run off while its covariance shrank)."""
        f, cfg = self.filter, self.cfg
        if f.published or not self._imu_fresh(t):
            f.motion.interrupt()  # nothing left to fit, or no IMU to fit
            return
        f.motion.add_frame(t, frame.p_w, f.R_nom)
        fit = f.motion.fit()
        if att is None or fit is None or not fit[1] <= cfg.coarse_scale_std:
            return
        std = float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]))
        surer = fit[1] < std and f.scale_source != "given"
        if surer or abs(fit[0] - f.x[LOG_SCALE]) > 3.0 * np.hypot(fit[1], std):
            log.info("fusion: scale %.3g m/unit from the IMU (+-%.1f%%), the filter had %.3g "
                     "(+-%.1f%%)", np.exp(fit[0]), 100 * fit[1], f.scale, 100 * std)
            f.rescale(frame.p_w, att.R_n_b, *fit)

    def _scene_height(self, t: float, frame: FrameInput, R_n_b: np.ndarray) -> None:
        """Fuse the map's height above the ground (its matched points' median depth along the
        vertical) against the rangefinder's, once per terrain_correlation_m flown."""
        f, cfg = self.filter, self.cfg
        points = frame.scene_w
        if not (cfg.use_scene_height and self._camera_down and f.has_ground
                and points is not None and len(points) >= MIN_SCENE_POINTS
                and self._range is not None and abs(t - self._range[0]) <= RANGE_FRESH_S):
            return
        if (f.scene_ne is not None
                and np.linalg.norm(f.x[:2] - f.scene_ne) < cfg.terrain_correlation_m):
            return
        heights = (points - frame.p_w) @ f.R_nom[2]  # R_nom[2]: N's down
        height = float(np.median(heights))
        spread = MAD_TO_SIGMA * float(np.median(np.abs(heights - height)))
        if height > 0 and np.isfinite(height) and m.update_scene(
                f, np.log(height), float((R_n_b @ f.lever)[2]), spread / height):
            f.scene_ne = f.x[:2].copy()

    def _scale_prior(self, t: float) -> tuple[float, float | None]:
        """ln(scale) and its std for a new map: from the rangefinder's distance when the camera
        looks down and a reading is fresh (the map's median depth is map_depth_units), else the
        last map's scale or the configured guess with the wide prior (None)."""
        cfg = self.cfg
        if (self._camera_down and self._range is not None
                and abs(t - self._range[0]) <= RANGE_FRESH_S):
            return float(np.log(self._range[1] / cfg.map_depth_units)), cfg.range_scale_prior_std
        f = self.filter
        return (float(f.x[LOG_SCALE]) if f.segment >= 0 else float(np.log(cfg.initial_scale)),
                None)

    def _attitude_noise(self, quality: str) -> np.ndarray:
        """Covariance of the autopilot's attitude (compass heading noisier than the tilt) plus
        a floor for the tracker's rotation (rad^2, N frame)."""
        cfg = self.cfg
        tilt, heading, vo = np.radians([cfg.attitude_std_deg, cfg.heading_std_deg,
                                        cfg.vo_rotation_std_deg])
        return np.diag([tilt**2, tilt**2, heading**2]) + np.eye(3) * vo**2 * inflation(
            cfg, quality)
