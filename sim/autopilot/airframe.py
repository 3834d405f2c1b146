"""The simulated multicopter's physical description: ArduPilot SITL's default quad
(libraries/SITL/SIM_Frame.cpp `default_model` and `Frame::init`), with the motor spin-up time
constants and the rotor yaw moment of PX4's x500 simulation model (PX4-gazebo-models
x500_base/model.sdf, MulticopterMotorModel), since SITL's own motors have none. What the
autopilot knows of it is only in its parameters (MOT_*, ATC_*), as on a real vehicle."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

GRAVITY = 9.80665
AIR_DENSITY = 1.225  # kg/m^3, standard sea level


@dataclass(frozen=True)
class Airframe:
    """A quad X whose motor numbering and spin directions are ArduPilot's (AP_MotorsMatrix
    setup_motors, QUAD X): 1 front right CCW, 2 back left CCW, 3 front left CW, 4 back right
    CW."""

    mass_kg: float = 3.0  # SIM_Frame.cpp default_model.mass
    diagonal_m: float = 0.35  # motor-to-motor diagonal, default_model.diagonal_size
    hover_thrust_ratio: float = 0.39  # hoverThrOut: thrust share of full thrust in a hover
    thrust_expo: float = 0.65  # propExpo: thrust = (1 - e) c + e c^2 of the motor command c
    motor_tau_up_s: float = 0.0125  # x500 model.sdf timeConstantUp
    motor_tau_down_s: float = 0.025  # x500 model.sdf timeConstantDown
    yaw_moment_m: float = 0.016  # x500 model.sdf momentConstant: reaction torque per newton
    disc_area_m2: float = 0.385  # default_model.disc_area, all four rotors
    momentum_drag: float = 0.2  # default_model.mdrag_coef
    ref_speed_ms: float = 15.08  # refSpd: the speed reached at refAngle of tilt ...
    ref_angle_deg: float = 45.0  # ... refAngle, which calibrates the bluff-body drag
    gear_height_m: float = 0.15  # body origin (IMU) above the ground when standing
    max_angular_rate: float = 30.0  # rad/s, a bound that keeps a broken loop finite

    @cached_property
    def inertia(self) -> np.ndarray:
        """Diagonal inertia (kg m^2): SITL's estimate when a model gives none, half the mass
        on a ring at the motors."""
        r2 = (0.5 * self.diagonal_m) ** 2
        return np.array([0.25 * self.mass_kg * r2, 0.25 * self.mass_kg * r2,
                         0.5 * self.mass_kg * r2])

    @cached_property
    def max_thrust_n(self) -> float:
        """One motor's full thrust: the four share the weight at hover_thrust_ratio."""
        return self.mass_kg * GRAVITY / (4 * self.hover_thrust_ratio)

    @cached_property
    def motor_positions(self) -> np.ndarray:
        """(4, 3) motor positions in body FRD (m), in ArduPilot's motor order."""
        arm = 0.5 * self.diagonal_m
        angles = np.radians([45.0, -135.0, -45.0, 135.0])  # from forward, clockwise
        return np.stack([arm * np.cos(angles), arm * np.sin(angles), np.zeros(4)], 1)

    @property
    def yaw_factors(self) -> np.ndarray:
        """+1 for a CCW propeller (its reaction turns the body clockwise, positive yaw)."""
        return np.array([1.0, 1.0, -1.0, -1.0])

    @cached_property
    def bluff_drag_area(self) -> float:
        """Drag area x Cd (m^2) such that the reference speed needs the reference tilt, after
        the rotors' momentum drag (Frame::init's areaCd)."""
        tilt = np.radians(self.ref_angle_deg)
        drag_force = self.mass_kg * GRAVITY * np.tan(tilt)
        thrust = self.mass_kg * GRAVITY / np.cos(tilt)
        airspeed_body = self.ref_speed_ms * np.cos(tilt)
        momentum = np.cos(tilt) * self.momentum_drag * airspeed_body * np.sqrt(
            thrust * AIR_DENSITY * self.disc_area_m2)
        return max(drag_force - momentum, 0.0) / (0.5 * AIR_DENSITY * self.ref_speed_ms ** 2)

    def thrust(self, command: np.ndarray) -> np.ndarray:
        """Thrust (N) of each motor at its command (0..1 between MOT_SPIN_MIN and MAX)."""
        c = np.clip(command, 0.0, 1.0)
        return self.max_thrust_n * ((1.0 - self.thrust_expo) * c + self.thrust_expo * c * c)
