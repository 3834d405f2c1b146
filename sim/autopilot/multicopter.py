"""Rigid-body physics of the simulated multicopter: four motors with spin-up lags and thrust
limits, rotor yaw moments, momentum and bluff-body drag against the (possibly gusty) air, gravity
and contact with flat ground. Motor commands in, true motion out; it knows nothing of the
autopilot.

The forces follow ArduPilot SITL's multicopter (libraries/SITL/SIM_Frame.cpp
`calculate_forces`, SIM_Motor.cpp): thrust (1 - e) c + e c^2 of full thrust along the body's up
axis, momentum drag sqrt(thrust x air density x disc area) x mdrag_coef x the body-horizontal
airspeed, bluff-body drag 0.5 rho areaCd v|v|. Integration is semi-implicit Euler at the step the
caller gives (the flight controller's 400 Hz loop). Ground contact: the vehicle stands level on
its gear until the thrust lifts it; touching down stops it and records the vertical speed, and
the accelerometer feels that stop over the gear's travel (a landing's spike in a flight log).
"""

from __future__ import annotations

import numpy as np

from sim.autopilot.airframe import AIR_DENSITY, GRAVITY, Airframe
from sim.autopilot.wind import WindField

FRICTION_TAU_S = 0.05  # sliding on the ground dies out this fast
GEAR_STOP_S = 0.02  # a touch-down's speed goes in the gear's few mm of travel (5 mm at 0.5 m/s)
GRAVITY_NED = np.array([0.0, 0.0, GRAVITY])


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_step(omega: np.ndarray, dt: float) -> np.ndarray:
    """exp(skew(omega dt)): the rotation a body turning at omega (rad/s) makes in dt."""
    angle = float(np.linalg.norm(omega)) * dt
    if angle < 1e-12:
        return np.eye(3)
    k = _skew(omega / np.linalg.norm(omega))
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class Multicopter:
    """The true state: position and velocity (NED, m, m/s), rotation body->NED, body rates
    (rad/s), the motors' effective commands and the specific force an accelerometer at the
    body origin feels."""

    def __init__(self, airframe: Airframe, position: np.ndarray, yaw: float,
                 ground_down_m: float, wind: WindField) -> None:
        self.frame = airframe
        self.ground_z = float(ground_down_m)
        self.contact_z = self.ground_z - airframe.gear_height_m
        self.position = np.array([position[0], position[1], self.contact_z], float)
        self.velocity = np.zeros(3)
        self.rotation = yaw_matrix(yaw)
        self.rates = np.zeros(3)
        self.motor = np.zeros(4)
        self.accel = np.zeros(3)
        self.specific_force = -GRAVITY_NED.copy()
        self.on_ground = True
        self.touchdown_speeds: list[float] = []
        self._gear_left = 0.0  # touch-down speed (m/s) the gear has still to take out
        self._gear_decel = 0.0  # and how fast (m/s^2)
        self.wind = wind
        self._steps = 0

    def step(self, dt: float, command: np.ndarray) -> None:
        """Advance by dt with the motors commanded to `command` (4, each 0..1)."""
        self._spin(np.clip(command, 0.0, 1.0), dt)
        thrusts = self.frame.thrust(self.motor)
        force_body, torque = self._body_forces(thrusts)
        air = self.velocity - self.wind.step(dt)
        force = self.rotation @ force_body + self._drag(air, thrusts.sum())
        self.accel = force / self.frame.mass_kg + GRAVITY_NED
        if self.on_ground and self.accel[2] >= 0.0:
            self._rest(dt)
        else:
            self.on_ground = False
            self._fly(dt, torque)
        self.specific_force = self.rotation.T @ (self.accel + self._gear_stop(dt) - GRAVITY_NED)

    def _gear_stop(self, dt: float) -> np.ndarray:
        """The gear's push (NED, m/s^2) taking out the last touch-down's speed over GEAR_STOP_S:
        the body stops at contact, the accelerometer feels it over the gear's travel."""
        taken = min(self._gear_left, self._gear_decel * dt)
        self._gear_left -= taken
        return np.array([0.0, 0.0, -taken / dt])

    def _spin(self, command: np.ndarray, dt: float) -> None:
        """Each motor approaches its command with the spin-up or spin-down time constant."""
        tau = np.where(command > self.motor, self.frame.motor_tau_up_s,
                       self.frame.motor_tau_down_s)
        self.motor = self.motor + (command - self.motor) * (1.0 - np.exp(-dt / tau))

    def _body_forces(self, thrusts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Total thrust along body up, and the torque of the thrusts about the centre plus the
        rotors' reaction moments."""
        pos = self.frame.motor_positions
        torque = np.array([-(pos[:, 1] * thrusts).sum(), (pos[:, 0] * thrusts).sum(),
                           self.frame.yaw_moment_m * (self.frame.yaw_factors * thrusts).sum()])
        return np.array([0.0, 0.0, -thrusts.sum()]), torque

    def _drag(self, air: np.ndarray, thrust: float) -> np.ndarray:
        """Momentum drag of the rotors (body-horizontal airspeed) and bluff-body drag (NED)."""
        air_body = self.rotation.T @ air
        k = self.frame.momentum_drag * np.sqrt(max(thrust, 0.0) * AIR_DENSITY *
                                               self.frame.disc_area_m2)
        momentum = self.rotation @ np.array([-k * air_body[0], -k * air_body[1], 0.0])
        bluff = -0.5 * AIR_DENSITY * self.frame.bluff_drag_area * np.linalg.norm(air) * air
        return momentum + bluff

    def _fly(self, dt: float, torque: np.ndarray) -> None:
        inertia = self.frame.inertia
        p, q, r = self.rates
        ix, iy, iz = inertia
        spin = np.array([q * r * (iz - iy), p * r * (ix - iz), p * q * (iy - ix)])  # w x Iw
        self.rates = np.clip(self.rates + (torque - spin) / inertia * dt,
                             -self.frame.max_angular_rate, self.frame.max_angular_rate)
        self.velocity = self.velocity + self.accel * dt
        self.position = self.position + self.velocity * dt
        self.rotation = self.rotation @ rotation_step(self.rates, dt)
        self._steps += 1
        if self._steps % 64 == 0:  # keep the rotation orthonormal
            u, _, vt = np.linalg.svd(self.rotation)
            self.rotation = u @ vt
        if self.position[2] >= self.contact_z:
            self._touch_down()

    def _touch_down(self) -> None:
        speed = float(self.velocity[2])
        self.touchdown_speeds.append(speed)
        self._gear_left, self._gear_decel = speed, speed / GEAR_STOP_S
        self.on_ground = True
        self.position[2] = self.contact_z
        self.velocity[2] = 0.0
        self._level()

    def _rest(self, dt: float) -> None:
        """Standing on the gear: no vertical motion, sliding dies out, level, not turning."""
        self.accel = np.zeros(3)
        self.velocity = self.velocity * np.exp(-dt / FRICTION_TAU_S)
        self.velocity[2] = 0.0
        self.position = self.position + self.velocity * dt
        self.position[2] = self.contact_z
        self._level()

    def _level(self) -> None:
        forward = self.rotation[:, 0]
        self.rotation = yaw_matrix(float(np.arctan2(forward[1], forward[0])))
        self.rates = np.zeros(3)
