"""ArduCopter's position controller (libraries/AC_AttitudeControl/AC_PosControl.cpp), in SI
units, steering on the EKF's estimate:

- a jerk-limited kinematic path (PSC_JERK_XY/Z) towards the mode's position or velocity, within
  the speed and acceleration limits the mode sets (input_pos_xyz, input_vel_accel_xy/z);
- horizontal: position P (PSC_POSXY_P, square-root law at the correction acceleration) -> velocity
  PID (PSC_VELXY_*) -> acceleration, limited by the lean angle (ANGLE_MAX or PSC_ANGLE_MAX) ->
  roll and pitch (accel_to_lean_angles); the heading follows the path's velocity above 5 % of the
  maximum speed (calculate_yaw_and_rate_yaw);
- vertical: position P (PSC_POSZ_P) -> velocity P (PSC_VELZ_P) -> acceleration target; the
  acceleration PID (PSC_ACCZ_*) on the measured vertical acceleration -> throttle around
  MOT_THST_HOVER runs in the 400 Hz loop (update_z_controller's last stage);
- EKF position resets move the targets with the estimate, keeping the errors
  (handle_ekf_xy_reset, handle_ekf_z_reset).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.autopilot.airframe import GRAVITY
from sim.autopilot.control_math import (
    KinematicPath,
    Pid,
    Pid2,
    limit_length,
    sqrt_controller,
    sqrt_controller_vec,
)
from sim.autopilot.param_store import ParamStore

YAW_SPEED_FRACTION = 0.05  # the heading follows the path above 5 % of the maximum speed


@dataclass(frozen=True)
class NavEstimate:
    """What the controllers see of the EKF: NED position and velocity, heading, and the
    accumulated position resets (metres) so a reset can be followed."""

    position: np.ndarray
    velocity: np.ndarray
    yaw: float
    reset_ne: np.ndarray
    reset_d: float


def stopping_distance(speed: float, p: float, accel: float) -> float:
    """Distance the square-root controller needs to stop from `speed` (stopping_distance)."""
    if p <= 0 or accel <= 0 or speed <= 0:
        return 0.0
    linear_speed = accel / p
    if speed <= linear_speed:
        return speed / p
    return accel / (2.0 * p * p) + speed * speed / (2.0 * accel)


class PositionControl:
    """Horizontal (NE) and vertical (up) position control; altitudes are up, as AP's U axis."""

    def __init__(self, params: ParamStore) -> None:
        self.params = params
        self.xy = KinematicPath(2)
        self.z = KinematicPath(1)
        self.vel_xy_pid = Pid2(*(params.get(f"PSC_VELXY_{k}") for k in ("P", "I", "D")),
                               params.get("PSC_VELXY_IMAX") / 100.0,
                               params.get("PSC_VELXY_FLTE"), params.get("PSC_VELXY_FLTD"))
        self.accel_z_pid = Pid(params.get("PSC_ACCZ_P"), params.get("PSC_ACCZ_I"),
                               params.get("PSC_ACCZ_D"), params.get("PSC_ACCZ_IMAX"),
                               filt_e_hz=params.get("PSC_ACCZ_FLTE"))
        self.xy_limits = (5.0, 1.0)  # speed m/s, accel m/s^2 (POSCONTROL_SPEED, _ACCEL_XY)
        self.z_limits = (1.5, 2.5, 2.5)  # down, up m/s, accel m/s^2 (POSCONTROL_*)
        self.accel_target = np.zeros(3)  # NE, up
        self.lean = (0.0, 0.0)
        self.yaw_target: float | None = None
        self.z_active = False
        self._limit_xy = np.zeros(2)
        self._resets = (np.zeros(2), 0.0)

    # --- limits --------------------------------------------------------------------------

    def set_xy_limits(self, speed: float, accel: float) -> None:
        self.xy_limits = (speed, accel)

    def set_z_limits(self, down: float, up: float, accel: float) -> None:
        self.z_limits = (abs(down), up, accel)

    def jerk_xy(self) -> float:
        """PSC_JERK_XY, no more than the lean-angle controller can follow."""
        accel_rp = math.radians(self.params.get("ATC_ACCEL_R_MAX") / 100.0)
        snap = accel_rp * GRAVITY
        return min(self.params.get("PSC_JERK_XY"), 0.5 * math.sqrt(self.xy_limits[1] * snap))

    def jerk_z(self) -> float:
        """PSC_JERK_Z, no more than the acceleration PID's error filter can follow."""
        flte = self.params.get("PSC_ACCZ_FLTE")
        limit = min(GRAVITY, self.z_limits[2]) * 2 * math.pi * flte / 5.0 if flte > 0 else 1e9
        return min(self.params.get("PSC_JERK_Z"), limit)

    # --- horizontal ------------------------------------------------------------------------

    def init_xy(self, nav: NavEstimate, lean_accel: np.ndarray) -> None:
        """init_xy_controller: path at the estimate, integrator from the present lean."""
        self.xy.reset(nav.position[:2], nav.velocity[:2])
        self.vel_xy_pid.reset_filter()
        self.vel_xy_pid.integrator = np.array(lean_accel, float)
        self._resets = (nav.reset_ne.copy(), self._resets[1])

    def stopping_point_xy(self, nav: NavEstimate) -> np.ndarray:
        speed = float(np.linalg.norm(nav.velocity[:2]))
        distance = stopping_distance(min(speed, self.xy_limits[0]),
                                     self.params.get("PSC_POSXY_P"), self.xy_limits[1])
        if speed <= 0:
            return nav.position[:2].copy()
        return nav.position[:2] + nav.velocity[:2] * (distance / speed)

    def hold_xy(self, point: np.ndarray) -> None:
        """Target a fixed point with no path velocity (init_xy_controller_stopping_point)."""
        self.xy.reset(point, np.zeros(2))

    def input_pos_xy(self, target: np.ndarray, dt: float) -> None:
        self.xy.advance(dt)
        self.xy.to_position(target, self.xy_limits[0], self.xy_limits[1], self.jerk_xy(), dt)

    def input_vel_xy(self, vel: np.ndarray, dt: float) -> None:
        self.xy.advance(dt)
        self.xy.to_velocity(vel, self.xy_limits[1], self.jerk_xy(), dt)

    def update_xy(self, nav: NavEstimate, angle_max: float, dt: float) -> None:
        """update_xy_controller: lean angles (and the heading of the path) for this step."""
        self._follow_xy_reset(nav)
        p = self.params.get("PSC_POSXY_P")
        correction = sqrt_controller_vec(self.xy.pos - nav.position[:2], p, self.xy_limits[1], dt)
        correction, _ = limit_length(correction, self.xy_limits[0])
        vel_target = correction + self.xy.vel
        accel = self.vel_xy_pid.update(vel_target, nav.velocity[:2], dt, self._limit_xy)
        accel = accel + self.xy.acc
        accel, limited = limit_length(accel, GRAVITY * math.tan(angle_max))
        self._limit_xy = accel if limited else np.zeros(2)
        self.accel_target[:2] = accel
        self.lean = accel_to_lean(accel, nav.yaw)
        speed = float(np.linalg.norm(self.xy.vel))
        if speed > YAW_SPEED_FRACTION * self.xy_limits[0]:
            self.yaw_target = math.atan2(self.xy.vel[1], self.xy.vel[0])

    def _follow_xy_reset(self, nav: NavEstimate) -> None:
        step = nav.reset_ne - self._resets[0]
        if np.any(step != 0):
            self.xy.pos = self.xy.pos + step
        self._resets = (nav.reset_ne.copy(), self._resets[1])

    # --- vertical --------------------------------------------------------------------------

    def init_z(self, nav: NavEstimate, throttle_in: float, hover: float) -> None:
        """init_z_controller: path at the estimate, acceleration integrator from the throttle."""
        self.z.reset([-nav.position[2]], [-nav.velocity[2]])
        self.accel_z_pid.reset()
        self.accel_z_pid.integrator = (throttle_in - hover) * 1000.0
        self._resets = (self._resets[0], nav.reset_d)
        self.z_active = True

    def input_pos_z(self, alt: float, dt: float) -> None:
        """input_pos_vel_accel_z towards an altitude (up, m) within the z limits."""
        down, up, accel = self.z_limits
        self.z.advance(dt)
        kpv = 0.5 * self.jerk_z() / accel
        vel = min(max(sqrt_controller(alt - self.z.pos[0], kpv, 0.5 * accel, dt), -down), up)
        self.z.to_velocity([vel], accel, self.jerk_z(), dt)

    def input_climb_rate(self, rate: float, dt: float) -> None:
        """set_pos_target_z_from_climb_rate_cm (input_vel_accel_z)."""
        down, up, accel = self.z_limits
        self.z.advance(dt)
        self.z.to_velocity([min(max(rate, -down), up)], accel, self.jerk_z(), dt)

    def update_z(self, nav: NavEstimate, dt: float) -> None:
        """update_z_controller up to the acceleration target (up, m/s^2)."""
        step = nav.reset_d - self._resets[1]
        if step != 0:
            self.z.pos = self.z.pos - step  # an NED reset of +d moves the altitude by -d
        self._resets = (self._resets[0], nav.reset_d)
        down, up, _ = self.z_limits
        error = self.z.pos[0] - (-nav.position[2])
        vel = min(max(sqrt_controller(error, self.params.get("PSC_POSZ_P"), self.z_limits[2], dt),
                      -down), up) + self.z.vel[0]
        self.accel_target[2] = self.params.get("PSC_VELZ_P") * (vel + nav.velocity[2]) + \
            self.z.acc[0]

    def throttle(self, accel_up: float, hover: float, dt: float, saturated: bool) -> float:
        """The acceleration PID (cm/s^2 gains, as the parameters): throttle for the measured
        vertical acceleration (400 Hz)."""
        self.accel_z_pid.imax = max(self.params.get("PSC_ACCZ_IMAX"), hover * 1000.0)
        out = self.accel_z_pid.update(self.accel_target[2] * 100.0, accel_up * 100.0, dt,
                                      saturated)
        return out * 0.001 + hover


def accel_to_lean(accel: np.ndarray, yaw: float) -> tuple[float, float]:
    """Roll and pitch (rad) that tilt the thrust to give a horizontal NE acceleration."""
    forward = accel[0] * math.cos(yaw) + accel[1] * math.sin(yaw)
    right = -accel[0] * math.sin(yaw) + accel[1] * math.cos(yaw)
    pitch = math.atan(-forward / GRAVITY)
    return math.atan(right * math.cos(pitch) / GRAVITY), pitch


def lean_to_accel(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The NE acceleration a lean gives (lean_angles_to_accel_xy)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    scale = GRAVITY / max(cr * cp, 0.1)
    return np.array([(-cy * sp * cr - sy * sr) * scale, (-sy * sp * cr + cy * sr) * scale])
