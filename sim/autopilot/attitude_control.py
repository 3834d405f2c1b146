"""ArduCopter's attitude controller (libraries/AC_AttitudeControl: AC_AttitudeControl,
AC_AttitudeControl_Multi), run at the 400 Hz loop rate on the AHRS attitude and the filtered
gyro:

- input shaping: the target attitude moves towards what the flight mode asks (roll, pitch and a
  yaw angle or rate) through feed-forward rates limited by ATC_ACCEL_R/P/Y_MAX and smoothed by
  ATC_INPUT_TC (input_shaping_angle / input_shaping_ang_vel);
- angle P: the error between target and AHRS attitude (a body-frame rotation vector) gives a
  rate correction through the square-root controller with ATC_ANG_RLL/PIT/YAW_P, plus the
  feed-forward rates turned to body rates (attitude_controller_run_quat);
- rate PIDs ATC_RAT_RLL/PIT/YAW_* on the filtered gyro, their integrators held while the motors
  saturate (rate_controller_run);
- throttle: boosted by 1/cos(tilt) to keep the vertical thrust (get_throttle_boosted), low-passed
  by the caller's cutoff (set_throttle_out).

The thrust-heading decomposition that limits yaw correction in large tilt errors, and the
throttle-versus-attitude mix (ATC_THR_MIX_*) beyond its floor, are not modelled.
"""

from __future__ import annotations

import math

import numpy as np

from sim.autopilot.control_math import Pid, lowpass_alpha, shape_angle, shape_rate, sqrt_controller
from sim.autopilot.motors import Limits
from sim.autopilot.param_store import ParamStore

AXES = ("RLL", "PIT", "YAW")


def euler_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body -> NED rotation of 3-2-1 Euler angles."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def matrix_to_euler(R: np.ndarray) -> tuple[float, float, float]:
    """3-2-1 Euler angles (roll, pitch, yaw) of a body -> NED rotation."""
    pitch = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Axis times angle of a rotation matrix."""
    cos = max(-1.0, min(1.0, 0.5 * (np.trace(R) - 1.0)))
    angle = math.acos(cos)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * axis
    return axis * (angle / (2.0 * math.sin(angle)))


def wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def euler_rates_to_body(roll: float, pitch: float, rates: np.ndarray) -> np.ndarray:
    """Body angular velocity of 3-2-1 Euler angle rates (euler_rate_to_ang_vel)."""
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    droll, dpitch, dyaw = rates
    return np.array([droll - sp * dyaw, cr * dpitch + sr * cp * dyaw,
                     -sr * dpitch + cr * cp * dyaw])


class AttitudeControl:
    """Targets in Euler angles (rad) with feed-forward Euler rates; `run` gives the roll,
    pitch and yaw outputs (-1..1) the motors mix."""

    def __init__(self, params: ParamStore) -> None:
        self.params = params
        self.pids = [self._pid(axis) for axis in AXES]
        self.target = np.zeros(3)  # roll, pitch, yaw
        self.ff_rate = np.zeros(3)  # Euler rates
        self.throttle_in = 0.0
        self.throttle_out = 0.0
        self.rate_target = np.zeros(3)
        self._desired = np.zeros(3)
        self._yaw_rate_mode = True
        self.refresh()

    def refresh(self) -> None:
        """Read the loop's gains and limits again (the flight modes' rate, not the loop's)."""
        p = self.params
        self._accel = np.radians([p.get(f"ATC_ACCEL_{a}_MAX") / 100.0 for a in "RPY"])
        self._angle_p = [p.get(f"ATC_ANG_{a}_P") for a in AXES]
        self._input_tc = max(p.get("ATC_INPUT_TC"), 0.01)
        self._slew_yaw = math.radians(p.get("ATC_SLEW_YAW") / 100.0)

    def _pid(self, axis: str) -> Pid:
        g = {k: self.params.get(f"ATC_RAT_{axis}_{k}") for k in
             ("P", "I", "D", "IMAX", "FLTT", "FLTE", "FLTD")}
        return Pid(g["P"], g["I"], g["D"], g["IMAX"], g["FLTT"], g["FLTE"], g["FLTD"])

    def angle_max(self) -> float:
        return math.radians(self.params.get("ANGLE_MAX") / 100.0)

    # --- inputs from the flight modes (50 Hz) ------------------------------------------------

    def input_euler_rate_yaw(self, roll: float, pitch: float, yaw_rate: float) -> None:
        """input_euler_angle_roll_pitch_euler_rate_yaw: lean angles and a heading rate."""
        self._desired = np.array([roll, pitch, yaw_rate])
        self._yaw_rate_mode = True

    def input_euler_yaw(self, roll: float, pitch: float, yaw: float) -> None:
        """input_euler_angle_roll_pitch_yaw: lean angles and a heading."""
        self._desired = np.array([roll, pitch, yaw])
        self._yaw_rate_mode = False

    def relax(self, attitude: np.ndarray) -> None:
        """relax_attitude_controllers: targets to the present attitude, no rates, integrators
        cleared (on the ground)."""
        self.target = np.array(matrix_to_euler(attitude))
        self.ff_rate = np.zeros(3)
        self._desired = np.array([self.target[0], self.target[1], 0.0])
        self._yaw_rate_mode = True
        for pid in self.pids:
            pid.reset()

    def set_throttle(self, throttle: float, boost: bool, cutoff_hz: float, attitude: np.ndarray,
                     dt: float) -> None:
        """set_throttle_out: the throttle (thrust fraction), tilt-compensated, low-passed."""
        self.throttle_in = throttle
        if boost:
            cos_tilt = attitude[2, 2]
            throttle = throttle * min(max(10.0 * cos_tilt, 0.0), 1.0) / max(cos_tilt, 0.5)
        self.throttle_out += (throttle - self.throttle_out) * lowpass_alpha(cutoff_hz, dt)

    # --- the 400 Hz loop ---------------------------------------------------------------------

    def run(self, attitude: np.ndarray, gyro: np.ndarray, dt: float,
            limit: Limits) -> np.ndarray:
        """One loop: shape the targets, angle P to rate targets, rate PIDs to outputs."""
        self._shape(dt)
        target = euler_to_matrix(*self.target)
        error = rotation_vector(attitude.T @ target)  # body frame
        accel = self._accel
        gains = self._angle_p
        correction = np.array([sqrt_controller(error[k], gains[k], accel[k], dt)
                               for k in range(3)])
        body_ff = euler_rates_to_body(self.target[0], self.target[1], self.ff_rate)
        self.rate_target = correction + body_ff
        limits = (limit.roll, limit.pitch, limit.yaw)
        return np.array([min(max(self.pids[k].update(self.rate_target[k], gyro[k], dt,
                                                     limits[k]), -1.0), 1.0)
                         for k in range(3)])

    def _shape(self, dt: float) -> None:
        tc = self._input_tc
        accel = self._accel
        for k in (0, 1):
            error = self._desired[k] - self.target[k]
            self.ff_rate[k] = shape_angle(error, 1.0 / tc, accel[k], self.ff_rate[k], dt)
        if self._yaw_rate_mode:
            self.ff_rate[2] = shape_rate(self.ff_rate[2], self._desired[2], accel[2], dt)
        else:
            slew = self._slew_yaw
            error = wrap_pi(self._desired[2] - self.target[2])
            rate = shape_angle(error, 1.0 / tc, accel[2], self.ff_rate[2], dt)
            self.ff_rate[2] = min(max(rate, -slew), slew)
        self.target = self.target + self.ff_rate * dt
        self.target[2] = wrap_pi(self.target[2])
