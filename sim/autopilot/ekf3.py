"""A stand-in for ArduPilot's EKF3, faithful where a vision companion meets it
(libraries/AP_NavEKF3, upstream mid-2025):

- starts ("EKF3 IMU0 initialised", "tilt alignment complete", with a compass "MAG0 initial yaw
  alignment complete") `ready_after_s` after boot, at height 0 with the barometer zeroed there
  (AP_Baro calibrates the ground pressure at boot).
- external nav is stored at most every 20 ms (extNavIntervalMin_ms), at its time minus
  VISO_DELAY_MS; a new reset time from AP_VisualOdom marks the sample as a position reset.
- it starts using external nav (Control.cpp setAidingMode/readyToUseExtNav) when
  EK3_SRC1_POSXY is 6, tilt is aligned and a sample is there: "EKF3 IMU0 is using external nav
  data", "EKF3 IMU0 initial pos NED = x,y,z (m)" (and "initial vel NED" with external nav
  velocity); position and velocity are reset to it and the height to its z whatever
  EK3_SRC1_POSZ says (ResetHeight with hgtMea = -extNavDataDelayed.pos.z), its variance the
  sample's constrain(posErr, 0.1, 10)^2: how fast the barometer then pulls a wrong height back
  depends on the covariance the companion sent.
- while using it (PosVelFusion.cpp SelectVelPosFusion/FuseVelPosNED): position fused with
  variance constrain(posErr, 0.01, 10)^2, velocity (EK3_SRC1_VELXY/VELZ 6) constrain(err, 0.05,
  5)^2, height from EK3_SRC1_POSZ (1 baro with EK3_ALT_M_NSE, 6 external nav with
  constrain(posErr, 0.1, 10)^2), gates EK3_*_I_GATE/100 sigma; a position reset
  (reset_counter change) is ResetPositionNE (and ResetPositionD with external nav height).
- position not fused for 7 s (10 s with velocity aiding) is a timeout: the next sample resets
  the position; nothing fused for 15 s stops aiding ("EKF3 IMU0 stopped aiding").
- the camera's VISO_POS_X/Y/Z lever arm is taken off position and velocity (turned by the
  attitude; CorrectExtNavForSensorOffset, CorrectExtNavVelForSensorOffset).
- resetHeightDatum on arming without home: the barometer re-zeroed and the height set to 0.
- ground effect (Copter's GND_EFFECT_COMP flags): while a takeoff is expected the baro height is
  held no lower than before the takeoff (selectHeightForFusion's meaHgtAtTakeOff, 0.5 s filter);
  while a takeoff or touchdown is expected the baro noise is 4x (gndEffectBaroScaler), and in a
  touchdown a baro reading low by up to EK3_GND_EFF_DZ is not believed (FuseVelPosNED).
- position resets are accumulated (getLastPosNorthEastReset / getLastPosDownReset) so the
  position controller can move its targets with them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from sim.autopilot.nav_filter import NavFilter
from sim.autopilot.param_store import ParamStore
from sim.autopilot.position_control import NavEstimate
from sim.autopilot.records import AutopilotRecord, EstimateSample, Event, EventKind, Severity
from sim.autopilot.sensing import Reading
from sim.autopilot.visual_odom import ExtNavPose, ExtNavVelocity

EXTNAV_INTERVAL_MIN_S = 0.02
POS_RETRY_NO_VEL_S = 7.0  # posRetryTimeNoVel_ms
POS_RETRY_VEL_S = 10.0  # posRetryTimeUseVel_ms
TILT_DRIFT_MAX_S = 15.0  # tiltDriftTimeMax_ms
HGT_RETRY_S = (5.0, 10.0)  # hgtRetryTimeMode12_ms, hgtRetryTimeMode0_ms (with vertical vel)
BARO_PERIOD_S = 0.05
RECORD_PERIOD_S = 0.1
NO_AID_POS_VAR = 0.5 ** 2  # R_OBS for the constant position fused while not aiding
GND_EFFECT_BARO_SCALER = 4.0  # gndEffectBaroScaler
TAKEOFF_HGT_TC_S = 0.5  # gndHgtFiltTC
EXTNAV_SOURCE = 6
BARO_SOURCE = 1


class AidMode(Enum):
    NONE = "none"
    ABSOLUTE = "absolute"


@dataclass
class Timers:
    last_pos_pass: float = -np.inf
    last_vel_pass: float = -np.inf
    last_hgt_pass: float = -np.inf
    last_baro: float = -np.inf
    last_record: float = -np.inf


class Ekf3:
    """Time-stepped: `step(now, reading)` at the IMU rate, `write_ext_nav*` as AP_VisualOdom
    delivers; `say(severity, text)` sends STATUSTEXT."""

    def __init__(self, params: ParamStore, say, record: AutopilotRecord, boot_time: float,
                 ready_after_s: float) -> None:
        self.params = params
        self.say = say
        self.record = record
        self.ready_at = boot_time + ready_after_s
        self.filter = NavFilter(params.get("EK3_ACC_P_NSE"))
        self.started = False
        self.aid = AidMode.NONE
        self.timers = Timers()
        self.ratios = {"vel": 0.0, "pos": 0.0, "hgt": 0.0}
        self.baro_offset = 0.0
        self.last_known_ne = np.zeros(2)
        self._pos: ExtNavPose | None = None
        self._vel: ExtNavVelocity | None = None
        self._last_meas_time = -np.inf
        self._last_reset_time = 0.0
        self._last_vel: ExtNavVelocity | None = None
        self.reset_ne = np.zeros(2)
        self.reset_d = 0.0
        self.takeoff_expected = False
        self.touchdown_expected = False
        self._hgt_at_takeoff = 0.0
        self.yaw = 0.0

    # --- inputs from AP_VisualOdom ---------------------------------------------------------

    def write_ext_nav(self, pose: ExtNavPose) -> None:
        """writeExtNavData: samples closer than 20 ms to the last are dropped."""
        if not np.isfinite(pose.position).all() or not self.started:
            return
        if pose.time_s - self._last_meas_time < EXTNAV_INTERVAL_MIN_S:
            return
        self._last_meas_time = pose.time_s
        self._pos = pose

    def write_ext_nav_vel(self, velocity: ExtNavVelocity) -> None:
        if np.isfinite(velocity.velocity).all() and self.started:
            self._vel = velocity
            self._last_vel = velocity

    # --- source helpers --------------------------------------------------------------------

    def _src(self, name: str) -> int:
        return int(self.params.get(f"EK3_SRC1_{name}"))

    def _gate(self, name: str) -> float:
        return max(self.params.get(f"EK3_{name}_I_GATE") / 100.0, 1.0)

    @property
    def use_compass(self) -> bool:
        return self._src("YAW") in (1, 3) and self.params.get("COMPASS_USE") > 0

    @property
    def using_extnav_for_yaw(self) -> bool:
        return self._src("YAW") == EXTNAV_SOURCE and self.aid is AidMode.ABSOLUTE

    @property
    def yaw_aligned(self) -> bool:
        return self.started and (self.use_compass or self.using_extnav_for_yaw)

    # --- the time step ---------------------------------------------------------------------

    def step(self, now: float, reading: Reading, dt: float) -> None:
        if not self.started:
            if now >= self.ready_at:
                self._start(reading)
            return
        accel = reading.accel_ned if np.isfinite(reading.accel_ned).all() else np.zeros(3)
        self.yaw = float(reading.attitude.as_euler("ZYX")[0])
        if reading.accel_steps is not None and np.isfinite(reading.accel_steps).all():
            self.filter.predict_steps(reading.accel_steps, dt, now)  # at the IMU rate
        else:
            self.filter.predict(accel, dt, now)
        if self._pos is not None:
            self._pos = self._lever_arm(self._pos, reading)
        self._update_aiding(now)
        if self._pos is not None:
            self._fuse_ext_nav(self._pos, now)
            self._pos = None
        if self._vel is not None:
            self._fuse_ext_nav_vel(self._lever_arm_vel(self._vel, reading), now)
            self._vel = None
        if now - self.timers.last_baro >= BARO_PERIOD_S and np.isfinite(reading.baro_alt):
            self.timers.last_baro = now
            self._fuse_baro(reading.baro_alt, now)
        if now - self.timers.last_record >= RECORD_PERIOD_S:
            self.timers.last_record = now
            self.record.estimates.append(EstimateSample(
                now, self.filter.position.copy(), self.filter.velocity.copy(),
                self.aid is AidMode.ABSOLUTE))

    def _offset(self) -> np.ndarray:
        return np.array([self.params.get(f"VISO_POS_{axis}") for axis in "XYZ"])

    def _lever_arm(self, pose: ExtNavPose, reading: Reading) -> ExtNavPose:
        """CorrectExtNavForSensorOffset: the camera's position minus its VISO_POS_* offset
        turned into NED, the vehicle's position."""
        shift = reading.attitude.apply(self._offset())
        return replace(pose, position=pose.position - shift)

    def _lever_arm_vel(self, velocity: ExtNavVelocity, reading: Reading) -> ExtNavVelocity:
        """CorrectExtNavVelForSensorOffset: less the camera's velocity from rotating about the
        vehicle."""
        spin = reading.attitude.apply(np.cross(reading.rates, self._offset()))
        return replace(velocity, velocity=velocity.velocity - spin)

    def _start(self, reading: Reading) -> None:
        """InitialiseFilterBootstrap and the alignment that follows on a still vehicle."""
        self.started = True
        if np.isfinite(reading.baro_ground):  # AP_Baro calibrates its ground pressure at boot
            self.baro_offset = reading.baro_ground
        self.timers.last_hgt_pass = self.ready_at
        self.say(Severity.INFO, "EKF3 IMU0 initialised")
        self.say(Severity.INFO, "EKF3 IMU0 tilt alignment complete")
        if self.use_compass:
            self.say(Severity.INFO, "EKF3 IMU0 MAG0 initial yaw alignment complete")

    def _update_aiding(self, now: float) -> None:
        if self.aid is AidMode.NONE:
            if self._src("POSXY") == EXTNAV_SOURCE and self._pos is not None:
                self._start_ext_nav(self._pos, now)
            return
        vel_aiding = now - self.timers.last_vel_pass <= POS_RETRY_NO_VEL_S
        if (now - self.timers.last_pos_pass > TILT_DRIFT_MAX_S and not vel_aiding):
            self._stop_aiding(now)

    def _start_ext_nav(self, pose: ExtNavPose, now: float) -> None:
        """setAidingMode's AID_ABSOLUTE with readyToUseExtNav()."""
        self.aid = AidMode.ABSOLUTE
        x, y, z = pose.position
        self.say(Severity.INFO, "EKF3 IMU0 is using external nav data")
        self.say(Severity.INFO, f"EKF3 IMU0 initial pos NED = {x:3.1f},{y:3.1f},{z:3.1f} (m)")
        use_vel = self._src("VELXY") == EXTNAV_SOURCE and self._fresh_vel(now)
        if use_vel:
            vx, vy, vz = self._last_vel.velocity
            self.say(Severity.INFO,
                     f"EKF3 IMU0 initial vel NED = {vx:3.1f},{vy:3.1f},{vz:3.1f} (m/s)")
        step = self._reset_position([2], [z], min(max(pose.pos_err, 0.1), 10.0) ** 2)
        self.record.events.append(Event(now, EventKind.HEIGHT_RESET, "external nav start",
                                        float(-step[2])))
        self._reset_position([0, 1], [x, y], pose.pos_err ** 2)
        if use_vel:
            self.filter.reset([0, 1], self._last_vel.velocity[:2], self._last_vel.err ** 2, 1)
        else:
            self.filter.reset([0, 1], [0.0, 0.0], 25.0 ** 2, 1)
        self.timers.last_pos_pass = self.timers.last_vel_pass = now
        self._last_reset_time = pose.reset_time_s
        self.record.events.append(Event(now, EventKind.EXTNAV_STARTED, f"{x:.2f},{y:.2f},{z:.2f}"))

    def _stop_aiding(self, now: float) -> None:
        self.aid = AidMode.NONE
        self.last_known_ne = self.filter.position[:2].copy()
        self.say(Severity.WARNING, "EKF3 IMU0 stopped aiding")
        self.record.events.append(Event(now, EventKind.EXTNAV_STOPPED))

    def _fresh_vel(self, now: float) -> bool:
        return self._last_vel is not None and now - self._last_vel.time_s < 0.25

    # --- fusion ----------------------------------------------------------------------------

    def _fuse_ext_nav(self, pose: ExtNavPose, now: float) -> None:
        if self.aid is not AidMode.ABSOLUTE or self._src("POSXY") != EXTNAV_SOURCE:
            return
        t_meas = pose.time_s - pose.delay_s
        if pose.reset_time_s != self._last_reset_time:
            self._last_reset_time = pose.reset_time_s
            self._reset_to(pose, now, "reset_counter changed")
            return
        fused = self.filter.fuse([0, 1], pose.position[:2], min(max(pose.pos_err, 0.01), 10.0) ** 2,
                                 t_meas, 0, self._gate("POS"))
        self.ratios["pos"] = fused.test_ratio
        retry = POS_RETRY_VEL_S if now - self.timers.last_vel_pass < 1.0 else POS_RETRY_NO_VEL_S
        if fused.accepted:
            self.timers.last_pos_pass = now
        elif now - self.timers.last_pos_pass > retry:
            self._reset_to(pose, now, "position timeout")
        if self._src("POSZ") == EXTNAV_SOURCE:
            self._fuse_height(-pose.position[2], min(max(pose.pos_err, 0.1), 10.0) ** 2,
                              t_meas, now)

    def _reset_to(self, pose: ExtNavPose, now: float, why: str) -> None:
        """ResetPositionNE, with ResetPositionD when external nav is the height source."""
        step = self._reset_position([0, 1], pose.position[:2], pose.pos_err ** 2)
        self.timers.last_pos_pass = now
        self.record.events.append(Event(now, EventKind.POSITION_RESET, why,
                                        float(np.hypot(step[0], step[1]))))
        if self._src("POSZ") == EXTNAV_SOURCE:
            step = self._reset_position([2], [pose.position[2]], pose.pos_err ** 2)
            self.record.events.append(Event(now, EventKind.HEIGHT_RESET, why, float(-step[2])))

    def _fuse_ext_nav_vel(self, velocity: ExtNavVelocity, now: float) -> None:
        if self.aid is not AidMode.ABSOLUTE or self._src("VELXY") != EXTNAV_SOURCE:
            return
        axes = [0, 1, 2] if self._src("VELZ") == EXTNAV_SOURCE else [0, 1]
        fused = self.filter.fuse(axes, velocity.velocity[axes],
                                 min(max(velocity.err, 0.05), 5.0) ** 2,
                                 velocity.time_s - velocity.delay_s, 1, self._gate("VEL"))
        self.ratios["vel"] = fused.test_ratio
        if fused.accepted:
            self.timers.last_vel_pass = now

    def _fuse_baro(self, baro_alt: float, now: float) -> None:
        if self.aid is AidMode.NONE:
            self.filter.fuse([0, 1], self.last_known_ne, NO_AID_POS_VAR, now, 0, 1e3)
        height = baro_alt - self.baro_offset
        if not self.takeoff_expected:
            alpha = BARO_PERIOD_S / (BARO_PERIOD_S + TAKEOFF_HGT_TC_S)
            self._hgt_at_takeoff += (height - self._hgt_at_takeoff) * alpha
        if self._src("POSZ") != BARO_SOURCE:
            return
        noise = min(max(self.params.get("EK3_ALT_M_NSE"), 0.1), 10.0)
        if self.takeoff_expected:
            height = max(height, self._hgt_at_takeoff)
        if self.touchdown_expected:
            estimate = -self.filter.position[2]
            if height < estimate:  # reads low near the ground: a dead zone
                height = min(height + self.params.get("EK3_GND_EFF_DZ"), estimate)
        if self.takeoff_expected or self.touchdown_expected:
            noise *= GND_EFFECT_BARO_SCALER
        self._fuse_height(height, noise ** 2, now, now)

    def _reset_position(self, axes: list[int], value: list | np.ndarray, var: float) -> np.ndarray:
        """Reset position axes; the step is remembered for the controllers."""
        step = self.filter.reset(axes, value, var, 0)
        self.reset_ne = self.reset_ne + step[:2]
        self.reset_d += float(step[2])
        return step

    def estimate(self) -> NavEstimate:
        """What the controllers steer with (AP_InertialNav's view of the EKF)."""
        return NavEstimate(self.filter.position.copy(), self.filter.velocity.copy(), self.yaw,
                           self.reset_ne.copy(), self.reset_d)

    def _fuse_height(self, height: float, var: float, t_meas: float, now: float) -> None:
        fused = self.filter.fuse([2], np.array([-height]), var, t_meas, 0, self._gate("HGT"))
        self.ratios["hgt"] = fused.test_ratio
        if fused.accepted:
            self.timers.last_hgt_pass = now
        elif now - self.timers.last_hgt_pass > self._hgt_retry(now):
            step = self._reset_position([2], [-height], var)
            self.timers.last_hgt_pass = now
            self.record.events.append(Event(now, EventKind.HEIGHT_RESET, "height timeout",
                                            float(-step[2])))

    def _hgt_retry(self, now: float) -> float:
        vertical_vel = self._src("VELZ") == EXTNAV_SOURCE and now - self.timers.last_vel_pass < 1
        return HGT_RETRY_S[1] if vertical_vel else HGT_RETRY_S[0]

    # --- outputs ---------------------------------------------------------------------------

    def reset_height_datum(self, baro_alt: float, now: float, on_ground: bool) -> None:
        """resetHeightDatum (on the ground, not with a rangefinder height): the barometer reads
        0 here from now on and the height state is 0."""
        if not self.started or not on_ground or self._src("POSZ") == 2:
            return
        self.baro_offset = baro_alt
        self._hgt_at_takeoff = 0.0
        step = self._reset_position([2], [0.0], self.filter.variance(2, 0))
        self.record.events.append(Event(now, EventKind.HEIGHT_RESET, "height datum reset",
                                        float(-step[2])))

    def status(self, now: float) -> dict[str, bool]:
        """getFilterStatus's flags that matter here."""
        healthy = self.started and (self.yaw_aligned or (not self.use_compass
                                                         and self.aid is AidMode.NONE))
        pos_timeout = now - self.timers.last_pos_pass > POS_RETRY_NO_VEL_S
        vel_ok = now - self.timers.last_vel_pass < POS_RETRY_NO_VEL_S
        hgt_ok = now - self.timers.last_hgt_pass <= self._hgt_retry(now)
        normal_nav = self.aid is AidMode.ABSOLUTE and not pos_timeout
        return {"attitude": healthy, "horiz_vel": healthy and (normal_nav or vel_ok),
                "vert_vel": healthy and (hgt_ok or vel_ok), "horiz_pos_rel": healthy and normal_nav,
                "horiz_pos_abs": healthy and normal_nav, "vert_pos": healthy and hgt_ok,
                "const_pos_mode": healthy and self.aid is AidMode.NONE,
                "initialized": self.started}
