"""The control primitives ArduCopter's controllers are built from, in SI units, written from their
description in libraries/AP_Math/control.cpp and libraries/AC_PID (AC_PID, AC_PID_2D, AC_P_1D):

- the square-root controller: proportional near zero, then a square-root law so the second
  derivative it asks for never exceeds a limit, and never past the target in one step;
- input shaping: a target rate that moves towards what the square-root controller wants at most
  `accel_max` per second;
- jerk-limited kinematic shaping of a (position, velocity, acceleration) path towards a target;
- PID controllers with target, error and derivative low-pass filters (FLTT, FLTE, FLTD), an
  integrator limited to IMAX that stops growing while the output is saturated.
"""

from __future__ import annotations

import math

import numpy as np


def lowpass_alpha(cutoff_hz: float, dt: float) -> float:
    """The gain of a first-order low-pass at cutoff_hz sampled every dt (1 = no filter)."""
    if cutoff_hz <= 0:
        return 1.0
    return dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))


def sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float) -> float:
    """Correction rate for an error: linear (gain p) near zero, square root beyond, so that the
    rate of change it asks for stays under second_ord_lim; never more than error / dt."""
    if second_ord_lim <= 0:
        out = error * p
    elif p == 0:
        out = math.copysign(math.sqrt(2.0 * second_ord_lim * abs(error)), error)
    else:
        linear = second_ord_lim / (p * p)
        if abs(error) > linear:
            out = math.copysign(math.sqrt(2.0 * second_ord_lim * (abs(error) - 0.5 * linear)),
                                error)
        else:
            out = error * p
    if dt > 0 and abs(out) > abs(error) / dt:
        out = error / dt
    return out


def sqrt_controller_vec(error: np.ndarray, p: float, second_ord_lim: float,
                        dt: float) -> np.ndarray:
    """sqrt_controller along the error vector's direction."""
    length = math.sqrt(float(np.dot(error, error)))
    if length < 1e-12:
        return np.zeros_like(error)
    return error * (sqrt_controller(length, p, second_ord_lim, dt) / length)


def shape_rate(target_rate: float, desired_rate: float, accel_max: float, dt: float) -> float:
    """The target rate moved towards the desired one by at most accel_max * dt."""
    if accel_max <= 0:
        return desired_rate
    step = accel_max * dt
    return min(max(desired_rate, target_rate - step), target_rate + step)


def shape_angle(error: float, smoothing_gain: float, accel_max: float, target_rate: float,
                dt: float) -> float:
    """Input shaping of an angle error into a feed-forward rate (input_shaping_angle)."""
    desired = sqrt_controller(error, smoothing_gain, accel_max, dt)
    return shape_rate(target_rate, desired, accel_max, dt)


def limit_length(v: np.ndarray, limit: float) -> tuple[np.ndarray, bool]:
    """v scaled down to `limit` if longer; whether it was."""
    length = math.sqrt(float(np.dot(v, v)))
    if limit > 0 and length > limit:
        return v * (limit / length), True
    return v, False


class KinematicPath:
    """A jerk-limited path (position, velocity, acceleration along `dims` axes) shaped towards a
    target position or velocity: the kinematic feed-forward AC_PosControl follows."""

    def __init__(self, dims: int) -> None:
        self.pos = np.zeros(dims)
        self.vel = np.zeros(dims)
        self.acc = np.zeros(dims)

    def reset(self, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray | None = None) -> None:
        self.pos = np.array(pos, float)
        self.vel = np.array(vel, float)
        self.acc = np.zeros_like(self.pos) if acc is None else np.array(acc, float)

    def advance(self, dt: float) -> None:
        """update_pos_vel_accel: integrate the path by dt."""
        self.pos = self.pos + self.vel * dt + 0.5 * self.acc * dt * dt
        self.vel = self.vel + self.acc * dt

    def to_velocity(self, vel: np.ndarray, accel_max: float, jerk_max: float,
                    dt: float) -> None:
        """shape_vel_accel: acceleration towards the velocity, limited, then jerk-limited."""
        kpa = jerk_max / accel_max if accel_max > 0 else 0.0
        goal = sqrt_controller_vec(np.asarray(vel, float) - self.vel, kpa, jerk_max, dt)
        goal, _ = limit_length(goal, accel_max)
        change, _ = limit_length(goal - self.acc, jerk_max * dt)
        self.acc = self.acc + change

    def to_position(self, pos: np.ndarray, vel_max: float, accel_max: float, jerk_max: float,
                    dt: float) -> None:
        """shape_pos_vel_accel: a velocity towards the position that can stop in time (square
        root law braking at half of accel_max, the margin for the jerk-limited onset), limited
        to vel_max, reached under the jerk limit."""
        kpv = 0.5 * jerk_max / accel_max if accel_max > 0 else 0.0
        vel = sqrt_controller_vec(np.asarray(pos, float) - self.pos, kpv, 0.5 * accel_max, dt)
        vel, _ = limit_length(vel, vel_max)
        self.to_velocity(vel, accel_max, jerk_max, dt)


class Pid:
    """AC_PID for one axis: output = P e + I + D de/dt + FF target, e the filtered error."""

    def __init__(self, p: float, i: float, d: float, imax: float, filt_t_hz: float = 0.0,
                 filt_e_hz: float = 0.0, filt_d_hz: float = 0.0, ff: float = 0.0) -> None:
        self.kp, self.ki, self.kd, self.ff, self.imax = p, i, d, ff, imax
        self.filt = (filt_t_hz, filt_e_hz, filt_d_hz)
        self.reset()

    def reset(self) -> None:
        self.integrator = 0.0
        self.target = 0.0
        self.error = 0.0
        self.derivative = 0.0
        self._fresh = True

    def update(self, target: float, measurement: float, dt: float,
               limit: bool = False) -> float:
        """One step; `limit` (the output saturated) stops the integrator growing."""
        if self._fresh:
            self.target, self.error, self.derivative = target, target - measurement, 0.0
            self._fresh = False
        else:
            self.target += (target - self.target) * lowpass_alpha(self.filt[0], dt)
            error = self.target - measurement
            previous = self.error
            self.error += (error - self.error) * lowpass_alpha(self.filt[1], dt)
            rate = (self.error - previous) / dt
            self.derivative += (rate - self.derivative) * lowpass_alpha(self.filt[2], dt)
        if self.ki > 0 and not (limit and self.error * self.integrator > 0):
            self.integrator = min(max(self.integrator + self.ki * self.error * dt, -self.imax),
                                  self.imax)
        return (self.kp * self.error + self.integrator + self.kd * self.derivative
                + self.ff * self.target)


class Pid2:
    """AC_PID_2D: a PID on a 2-vector whose integrator is limited in length to IMAX and does
    not grow along the direction the output is being limited in."""

    def __init__(self, p: float, i: float, d: float, imax: float, filt_e_hz: float,
                 filt_d_hz: float) -> None:
        self.kp, self.ki, self.kd, self.imax = p, i, d, imax
        self.filt_e_hz, self.filt_d_hz = filt_e_hz, filt_d_hz
        self.reset_filter()
        self.integrator = np.zeros(2)

    def reset_filter(self) -> None:
        self.error = np.zeros(2)
        self.derivative = np.zeros(2)
        self._fresh = True

    def update(self, target: np.ndarray, measurement: np.ndarray, dt: float,
               limit: np.ndarray) -> np.ndarray:
        error = np.asarray(target, float) - measurement
        if self._fresh:
            self.error, self.derivative, self._fresh = error, np.zeros(2), False
        else:
            previous = self.error
            self.error = self.error + (error - self.error) * lowpass_alpha(self.filt_e_hz, dt)
            rate = (self.error - previous) / dt
            self.derivative = self.derivative + (rate - self.derivative) * \
                lowpass_alpha(self.filt_d_hz, dt)
        grow = self.ki * self.error * dt
        if np.dot(limit, limit) > 0 and np.dot(grow, limit) > 0:
            grow = np.zeros(2)  # do not wind up against the limit
        self.integrator, _ = limit_length(self.integrator + grow, self.imax)
        return self.kp * self.error + self.integrator + self.kd * self.derivative
