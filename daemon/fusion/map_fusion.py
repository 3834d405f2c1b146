"""One tracker frame into the navigation filter: a new map's start and scale prior, the pose
update with the autopilot's attitude, re-anchoring, re-alignment of a map that stopped fitting,
and, until the map converges, its scale from the climb, the IMU's motion or the scene's height
(none of these for a metric map, started from depth: its scale is 1).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from daemon.fusion import measurements as m
from daemon.fusion.alignment import AlignmentGate
from daemon.fusion.attitude import AttitudeTrack
from daemon.fusion.config import FusionConfig
from daemon.fusion.output import attitude_noise, inflation
from daemon.fusion.state import ANCHOR, LOG_SCALE, POS, TIME_OFFSET, NavFilter, ScaleSource
from vo.pose_optimizer import MAD_TO_SIGMA
from vo.result import Quality

log = logging.getLogger("sdvl.fusion")
TRACKED = (Quality.GOOD, Quality.INSUFFICIENT, Quality.BAD)
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
    fresh: bool = False  # the first frame of its map (whose median depth is map_depth_units)
    metric: bool = False  # its map is in metres (started from a depth map): no scale to find


def frame_input(result: object, R_c_b: np.ndarray, segment: int,
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
                      result.quality, segment, getattr(result, "scene_w", None),
                      bool(result.new_segment), bool(getattr(result, "metric", False)))


@dataclass
class Readings:
    """The newest rangefinder distance and barometric altitude, (time, value) on our clock."""

    range: tuple[float, float] | None = None
    baro: tuple[float, float] | None = None

    def fresh_range(self, t: float) -> float | None:
        """The rangefinder's distance when a reading is within RANGE_FRESH_S of t."""
        if self.range is None or abs(t - self.range[0]) > RANGE_FRESH_S:
            return None
        return self.range[1]


class MapFusion:
    """Frame updates of one NavFilter (kept by reference: the estimator restores it in place)."""

    def __init__(self, cfg: FusionConfig, nav: NavFilter, attitude: AttitudeTrack,
                 gate: AlignmentGate, readings: Readings, imu_fresh: Callable[[float], bool],
                 imu_density: Callable[[], np.ndarray], camera_down: bool):
        self.cfg, self.filter, self.attitude, self.gate = cfg, nav, attitude, gate
        self.readings, self.imu_fresh, self.camera_down = readings, imu_fresh, camera_down
        self.imu_density = imu_density  # the IMU stream's measured noise, per body axis
        self.ground_z: float | None = None  # NED z where the vehicle stood at the start

    def in_ground_effect(self) -> bool:
        """Whether the filter's height above where the vehicle stood at the start is below
        baro_ground_effect_height_m, where the rotors' ground effect moves the barometer
        (False when that level is unknown: the filter started moving)."""
        return (self.ground_z is not None
                and self.ground_z - float(self.filter.x[2]) < self.cfg.baro_ground_effect_height_m)

    def fuse(self, t: float, frame: FrameInput) -> None:
        """Fuse a tracker frame at the filter's time t: a new map starts (its anchor cloned from
        the vehicle, its scale prior), else the pose and the autopilot's attitude update the
        filter, the anchor moves along, and a map that keeps failing is re-aligned."""
        f = self.filter
        att = self.attitude.at(t)
        if f.segment != frame.segment:
            if att is None:
                return
            log_scale, std, source = self._scale_prior(t, frame, att.R_n_b)
            f.start_segment(frame.p_w, frame.R_w_b, att.R_n_b, log_scale, std,
                            metric=frame.metric, source=source)
            f.segment = frame.segment
            self.gate.restart()
            return
        metric = f.scale_source is ScaleSource.METRIC
        if not metric:  # a metric map has no scale to fit
            self._late_range_prior(t, frame, att)
            self._climb_scale(t, frame, att)
            self._accel_scale(t, frame, att)
        factor = inflation(self.cfg, frame.quality)
        imu = self.imu_fresh(t)  # without it the horizontal rows never touch the scale
        coarse = (self.cfg.coarse_inflation if imu and np.sqrt(f.P[LOG_SCALE, LOG_SCALE])
                  > self.cfg.coarse_scale_std else 1.0)
        R_n_b = f.R_nom @ frame.R_w_b
        attitude = (None if att is None
                    else (att.R_n_b, frame.R_w_b,
                          attitude_noise(self.cfg, frame.quality, att.gap_var)))
        if m.update_vo(f, frame.p_w, frame.cov, R_n_b, factor, imu, attitude,
                       coarse):
            if np.linalg.norm(f.x[POS] - f.x[ANCHOR]) > self.cfg.reanchor_distance_m:
                f.reanchor(frame.p_w, R_n_b)
            if not metric:
                self._scene_height(t, frame, R_n_b)
        elif f.rejections["vo"] >= self.cfg.reset_after_rejections and att is not None:
            self._realign(frame, att.R_n_b, metric)
        if f.scale_source is ScaleSource.PRIOR:
            f.forget_scale()

    def _realign(self, frame: FrameInput, R_n_b: np.ndarray, metric: bool) -> None:
        """The tracker's poses were rejected reset_after_rejections times in a row: the same
        map is re-anchored where it puts the camera now, its scale and its climb pairs kept,
        after the filter doubted its own motion (doubt_motion)."""
        f = self.filter
        f.realigns += 1
        f.doubt_motion()
        self.gate.restart()
        f.start_segment(frame.p_w, frame.R_w_b, R_n_b, f.x[LOG_SCALE],
                        float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE])), metric=metric, same_map=True)
        f.rejections["vo"] = 0

    def _late_range_prior(self, t: float, frame: FrameInput, att: object) -> None:
        """A map started before the rangefinder's first reading still has the wide prior:
        give it the scale start_segment would have given (the reading over the camera's height
        above the points it matched), once a reading comes. The service starts tracking as soon
        as frames come, before the autopilot streams DISTANCE_SENSOR (or while it reads below
        its minimum range on the ground); the real-time replay's map kept the wide prior
        until the IMU's fit in the climb."""
        f = self.filter
        if f.scale_source is not ScaleSource.PRIOR or att is None:
            return
        log_scale = self._range_scale(t, self._map_height_units(frame, att.R_n_b @ frame.R_w_b.T))
        if log_scale is None:
            return
        log.info("fusion: scale %.3g m/unit from the rangefinder's first reading",
                 np.exp(log_scale))
        self._rescale(frame.p_w, att.R_n_b, log_scale, self.cfg.range_scale_prior_std,
                      ScaleSource.GIVEN)

    def _rescale(self, p_w: np.ndarray, R_n_b: np.ndarray, log_scale: float, std: float,
                 source: ScaleSource = ScaleSource.FIT) -> None:
        """The filter takes a new scale (NavFilter.rescale); one whose IMU carries the vehicle
        first places it where the map puts it from the segment's start at that scale, as far
        as the two agree with their uncertainties (measurements.update_from_start)."""
        f = self.filter
        if f.imu_carries():
            m.update_from_start(f, p_w, R_n_b, log_scale, std)
        f.rescale(p_w, R_n_b, log_scale, std, source)

    def _range_scale(self, t: float, units: float | None) -> float | None:
        """ln(scale) from a fresh rangefinder reading over the camera's height above the ground
        in map units, with a downward camera (None: no such reading or height)."""
        distance = self.readings.fresh_range(t)
        if units is None or distance is None or not self.camera_down:
            return None
        return float(np.log(distance / units))

    def _climb_scale(self, t: float, frame: FrameInput, att: object) -> None:
        """Pair the tracker's height with the barometer's above the ground effect; while the
        filter does not know the scale from elsewhere (std above coarse_scale_std, or no IMU)
        and has not converged, take it from their fit over the climb when that is surer
        (climb_scale.py)."""
        f, cfg = self.filter, self.cfg
        if (self.readings.baro is None or abs(t - self.readings.baro[0]) > RANGE_FRESH_S
                or f.converged or self.in_ground_effect()):
            return  # once converged the fit is not used: pairing on would grow without bound
        f.climb.add(float((f.R_nom @ frame.p_w)[2]), *self.readings.baro)  # map's own origin
        std = float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]))
        if att is None or (std <= cfg.coarse_scale_std and self.imu_fresh(t)):
            return
        fit = f.climb.fit(cfg.climb_scale_min_m, cfg.baro_std_m)
        if fit is not None:  # the map's own scale wanders over the climb (its walk, halved)
            fit = (fit[0], float(np.hypot(fit[1], 0.5 * cfg.scale_walk_climb_per_sqrt_m
                                          * np.sqrt(f.climb.climb_m(fit[0])))))
        if fit is not None and fit[1] < std:
            log.info("fusion: scale %.3g m/unit from the climb (+-%.1f%%)", np.exp(fit[0]),
                     100 * fit[1])
            self._rescale(frame.p_w, att.R_n_b, *fit)

    def _accel_scale(self, t: float, frame: FrameInput, att: object) -> None:
        """Pair the map's position with the IMU's double integral; until the map converges,
        take the scale from their linear fit (accel_scale.py) once that is good to
        coarse_scale_std: when it is surer than a scale not given with the map (the wide prior,
        or an earlier fit), or more than 3 sigma away from the filter's (its linearised scale
        has run off while its covariance shrank)."""
        f, cfg = self.filter, self.cfg
        if f.converged or not self.imu_fresh(t):
            f.motion.interrupt()  # nothing left to fit, or no IMU to fit
            return
        f.motion.add_frame(t, frame.p_w, f.R_nom,
                           float(np.sqrt(np.mean(np.square(self.imu_density())))),
                           float(f.x[TIME_OFFSET]),
                           float(np.trace(frame.cov[:3, :3])) / 3.0)
        fit = f.motion.fit()
        if att is None or fit is None or not fit[1] <= cfg.coarse_scale_std:
            return
        std = float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]))
        surer = fit[1] < std and f.scale_source is not ScaleSource.GIVEN
        if surer or abs(fit[0] - f.x[LOG_SCALE]) > 3.0 * np.hypot(fit[1], std):
            log.info("fusion: scale %.3g m/unit from the IMU (+-%.1f%%), the filter had %.3g "
                     "(+-%.1f%%)", np.exp(fit[0]), 100 * fit[1], f.scale, 100 * std)
            self._rescale(frame.p_w, att.R_n_b, *fit)

    def _scene_height(self, t: float, frame: FrameInput, R_n_b: np.ndarray) -> None:
        """Fuse the map's height above the ground (its matched points' median depth along the
        vertical) against the rangefinder's, once per terrain_correlation_m flown."""
        f, cfg = self.filter, self.cfg
        points = frame.scene_w
        if not (cfg.use_scene_height and self.camera_down and f.has_ground
                and points is not None and len(points) >= MIN_SCENE_POINTS
                and self.readings.fresh_range(t) is not None):
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

    def _scale_prior(self, t: float, frame: FrameInput,
                     R_n_b: np.ndarray) -> tuple[float, float | None, ScaleSource | None]:
        """ln(scale), its std and where it came from (None: the std says) for a map the filter
        starts on: with a downward camera and a fresh rangefinder reading, the reading over
        the map's height in its own units: the median depth of the points the frame matched,
        or map_depth_units on the map's first frame (the tracker scales a new map so); without
        the rangefinder, the height above where the vehicle stood at the start (flat ground
        assumed, the std says how sure); else the last map's scale or the configured guess
        with the wide prior (None). A map started after the climb without a rangefinder had
        only the IMU's fit left, which a hover does not give: the IMU carried the vehicle
        alone and the autopilot's EKF failsafed on 9 of 10 seeds."""
        cfg, f = self.cfg, self.filter
        units = self._map_height_units(frame, R_n_b @ frame.R_w_b.T)
        if units is None and frame.fresh:
            units = cfg.map_depth_units
        log_scale = self._range_scale(t, units)
        if log_scale is not None:
            return log_scale, cfg.range_scale_prior_std, ScaleSource.GIVEN
        height = None if self.ground_z is None else self.ground_z - float(f.x[2])
        if units is not None and self.camera_down and height is not None and height > 0:
            # no rangefinder: the height above where it stood (barometer), as wrong as the
            # filter's height, the barometer's noise and the rotors' wash on it allow
            std = (float(np.sqrt(f.P[2, 2])) + cfg.baro_std_m) / height
            if std < cfg.nav_scale_std:  # FIT: a surer fit replaces it
                return float(np.log(height / units)), std, ScaleSource.FIT
        return (float(f.x[LOG_SCALE]) if f.segment >= 0 else float(np.log(cfg.initial_scale)),
                None, None)

    @staticmethod
    def _map_height_units(frame: FrameInput, R_n_w: np.ndarray) -> float | None:
        """The camera's height above the points it matched, map units (None: too few)."""
        points = frame.scene_w
        if points is None or len(points) < MIN_SCENE_POINTS:
            return None
        height = float(np.median((points - frame.p_w) @ R_n_w[2]))
        return height if height > 0 and np.isfinite(height) else None
