"""A stand-in for PX4's EKF2 external-vision fusion (src/modules/ekf2/EKF/aid_sources/
external_vision: ev_control.cpp, ev_pos_control.cpp, ev_height_control.cpp, ev_vel_control.cpp;
params_external_vision.yaml; EKF2.cpp's EV noise handling; v1.14+):

- EKF2_EV_CTRL bits: 0 horizontal position, 1 vertical position, 2 velocity, 3 yaw. Fusion
  starts on a sample whose quality passes EKF2_EV_QMIN (with the previous one) and that follows
  the previous within 200 ms (EV_MAX_INTERVAL); no sample for 400 ms stops it.
- starting horizontal position fusion resets the position to the sample ("reset_pos_to_vision");
  a LOCAL_FRD sample is turned into the EKF frame by the attitude difference (EKF attitude times
  the inverse of the sample's) unless EV yaw is fused, and its variance raised to the
  orientation variance; a LOCAL_NED one waits for the EKF's yaw alignment.
- EKF2_HGT_REF 3 (vision) with bit 1: starting EV height resets the altitude to the sample's z
  (a step when the vision frame's z origin is elsewhere); any other reference: EV height is
  fused through a bias estimate set at the start, so no step.
- reset_counter change (ev_reset): position reset to the sample, height reset (vision
  reference) or bias re-set (otherwise), velocity reset.
- noise: EKF2_EV_NOISE_MD 0 = the message's variance floored at EKF2_EVP/EVV/EVA_NOISE^2
  (parameter when absent), 1 = the parameters; gates EKF2_EVP_GATE, EKF2_EVV_GATE.
- the barometer (EKF2_BARO_CTRL) is the height reference unless vision is; no GNSS here.
- EKF2_EV_POS_X/Y/Z (the camera in the body frame) is taken off the position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sim.autopilot.nav_filter import NavFilter
from sim.autopilot.param_store import ParamStore
from sim.autopilot.records import AutopilotRecord, EstimateSample, Event, EventKind
from sim.autopilot.sensing import Reading

EV_MAX_INTERVAL_S = 0.2
HPOS, VPOS, VEL, YAW = 1, 2, 4, 8
VISION_HGT_REF = 3
BARO_PERIOD_S = 0.05
RECORD_PERIOD_S = 0.1
Q_ERROR_ALPHA = 0.1  # low-pass of the EKF-to-EV attitude difference (_ev_q_error_filt)


@dataclass(frozen=True)
class EvSample:
    """One external vision sample as mavlink_receiver publishes it (vehicle_visual_odometry)."""

    time_s: float  # on the autopilot's clock, before EKF2_EV_DELAY
    position: np.ndarray
    position_var: np.ndarray
    attitude: Rotation
    orientation_var: np.ndarray
    velocity: np.ndarray | None
    velocity_var: np.ndarray
    pos_frame: str  # "ned" or "frd"
    vel_frame: str  # "body", "ned" or "frd"
    reset_counter: int
    quality: int


class Ekf2:
    """Time-stepped like Ekf3: `push(sample)` on each vision message, `step` at IMU rate."""

    def __init__(self, params: ParamStore, record: AutopilotRecord, boot_time: float,
                 ready_after_s: float) -> None:
        self.params = params
        self.record = record
        self.ready_at = boot_time + ready_after_s
        self.filter = NavFilter(params.get("EKF2_ACC_NOISE"))
        self.started = False
        self.active = {"pos": False, "hgt": False, "vel": False}
        self.hgt_bias = 0.0
        self.baro_offset = 0.0
        self.hgt_ref_vision = False
        self._q_error: Rotation | None = None
        self._prev: EvSample | None = None
        self._pending: list[EvSample] = []
        self._attitude = Rotation.identity()
        self._last_ev = -np.inf
        self._last_baro = -np.inf
        self._last_record = -np.inf

    def push(self, sample: EvSample) -> None:
        if self.started and np.isfinite(sample.position).all():
            self._pending.append(sample)

    @property
    def ctrl(self) -> int:
        return int(self.params.get("EKF2_EV_CTRL"))

    def local_position_valid(self) -> bool:
        return self.active["pos"]

    def altitude_valid(self) -> bool:
        return self.started

    def step(self, now: float, reading: Reading, dt: float) -> None:
        self._attitude = reading.attitude
        if not self.started:
            if now >= self.ready_at:
                self.started = True
                if np.isfinite(reading.baro_ground):  # local z = 0 where the EKF started
                    self.baro_offset = reading.baro_ground
            return
        accel = reading.accel_ned if np.isfinite(reading.accel_ned).all() else np.zeros(3)
        self.filter.predict(accel, dt, now)
        for sample in self._pending:
            self._control(sample, now)
        self._pending.clear()
        if any(self.active.values()) and now - self._last_ev > 2 * EV_MAX_INTERVAL_S:
            self.active = dict.fromkeys(self.active, False)
            self.record.events.append(Event(now, EventKind.EXTNAV_STOPPED, "vision data stopped"))
        if now - self._last_baro >= BARO_PERIOD_S and not self.hgt_ref_vision and \
                np.isfinite(reading.baro_alt) and self.params.get("EKF2_BARO_CTRL") > 0:
            self._last_baro = now
            self.filter.fuse([2], np.array([self.baro_offset - reading.baro_alt]),
                             self.params.get("EKF2_BARO_NOISE") ** 2, now, 0, 5.0)
        if now - self._last_record >= RECORD_PERIOD_S:
            self._last_record = now
            self.record.estimates.append(EstimateSample(
                now, self.filter.position.copy(), self.filter.velocity.copy(),
                self.active["pos"]))

    def _control(self, sample: EvSample, now: float) -> None:
        """controlExternalVisionFusion for one sample."""
        prev = self._prev
        reset = sample.reset_counter != (prev.reset_counter if prev else 0)
        qmin = self.params.get("EKF2_EV_QMIN")
        quality_ok = qmin <= 0 or sample.quality >= qmin
        starting = quality_ok and prev is not None and \
            sample.time_s - prev.time_s < EV_MAX_INTERVAL_S and \
            (qmin <= 0 or prev.quality >= qmin)
        self._update_q_error(sample, reset)
        t_meas = sample.time_s - self.params.get("EKF2_EV_DELAY") / 1000.0
        position, pos_var = self._position(sample)
        if position is not None:
            self._control_pos(position, pos_var, t_meas, starting, reset, now)
            self._control_hgt(position[2], pos_var[2], t_meas, starting, reset, now)
        self._control_vel(sample, t_meas, starting, reset, now)
        self._last_ev = now
        if quality_ok:
            self._prev = sample

    def _update_q_error(self, sample: EvSample, reset: bool) -> None:
        q_error = self._attitude * sample.attitude.inv()
        if self._q_error is None or reset:
            self._q_error = q_error
        else:
            delta = (q_error * self._q_error.inv()).as_rotvec()
            self._q_error = Rotation.from_rotvec(Q_ERROR_ALPHA * delta) * self._q_error

    def _floor(self, var: np.ndarray, noise: float) -> np.ndarray:
        """EKF2_EV_NOISE_MD: the message's variance floored at the parameter, or the parameter
        alone (mode 1 or no variance in the message)."""
        floor = np.full(3, noise ** 2)
        if self.params.get("EKF2_EV_NOISE_MD") == 1 or not np.isfinite(var).all():
            return floor
        return np.maximum(var, floor)

    def _position(self, sample: EvSample) -> tuple[np.ndarray | None, np.ndarray]:
        """The sample in the EKF frame less the EKF2_EV_POS_* lever arm, and its variance."""
        var = np.maximum(self._floor(sample.position_var, self.params.get("EKF2_EVP_NOISE")),
                         0.01 ** 2)
        offset = self._attitude.apply([self.params.get(f"EKF2_EV_POS_{a}") for a in "XYZ"])
        if sample.pos_frame == "ned" or self.ctrl & YAW:
            return sample.position - offset, var  # NED: yaw aligned (magnetometer) here
        rotated = self._q_error.apply(sample.position)
        orientation = self._floor(sample.orientation_var, self.params.get("EKF2_EVA_NOISE"))
        return rotated - offset, np.maximum(var, orientation.max())

    def _control_pos(self, position: np.ndarray, var: np.ndarray, t_meas: float,
                     starting: bool, reset: bool, now: float) -> None:
        if not self.ctrl & HPOS:
            self.active["pos"] = False
            return
        if self.active["pos"] and not reset:
            self.filter.fuse([0, 1], position[:2], float(var[:2].max()), t_meas, 0,
                             max(self.params.get("EKF2_EVP_GATE"), 1.0))
        elif self.active["pos"] or starting:
            step = self.filter.reset([0, 1], position[:2], float(var[:2].max()), 0)
            kind = EventKind.POSITION_RESET if self.active["pos"] else EventKind.EXTNAV_STARTED
            self.record.events.append(Event(now, kind, "reset_pos_to_vision",
                                            float(np.hypot(step[0], step[1]))))
            self.active["pos"] = True

    def _control_hgt(self, z: float, var: float, t_meas: float, starting: bool, reset: bool,
                     now: float) -> None:
        if not self.ctrl & VPOS:
            self.active["hgt"] = False
            return
        vision_ref = int(self.params.get("EKF2_HGT_REF")) == VISION_HGT_REF
        if self.active["hgt"] and not reset:
            self.filter.fuse([2], np.array([z - self.hgt_bias]), var, t_meas, 0,
                             max(self.params.get("EKF2_EVP_GATE"), 1.0))
        elif self.active["hgt"] or starting:
            if vision_ref:
                step = self.filter.reset([2], [z], var, 0)
                self.hgt_bias = 0.0
                self.hgt_ref_vision = True
                self.record.events.append(Event(now, EventKind.HEIGHT_RESET, "reset to EV",
                                                float(-step[2])))
            else:
                self.hgt_bias = z - self.filter.position[2]
            self.active["hgt"] = True

    def _control_vel(self, sample: EvSample, t_meas: float, starting: bool, reset: bool,
                     now: float) -> None:
        if not self.ctrl & VEL or sample.velocity is None or \
                not np.isfinite(sample.velocity).all():
            self.active["vel"] = False
            return
        if sample.vel_frame == "body":
            velocity = self._attitude.apply(sample.velocity)
        elif sample.vel_frame == "frd" and not self.ctrl & YAW:
            velocity = self._q_error.apply(sample.velocity)
        else:
            velocity = sample.velocity
        var = float(self._floor(sample.velocity_var, self.params.get("EKF2_EVV_NOISE")).max())
        if self.active["vel"] and not reset:
            self.filter.fuse([0, 1, 2], velocity, var, t_meas, 1,
                             max(self.params.get("EKF2_EVV_GATE"), 1.0))
        elif self.active["vel"] or starting:
            self.filter.reset([0, 1, 2], velocity, var, 1)
            self.active["vel"] = True
