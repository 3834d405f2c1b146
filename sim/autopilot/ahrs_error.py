"""How the autopilot's attitude (AHRS/EKF, ATTITUDE) differs from the truth:

- tilt: the filter levels itself on the accelerometer, so the horizontal part of the IMU's
  residual offset shows as a tilt error of offset / g (the offset's horizontal acceleration and
  the tilt cancel in a hover, as they do in a real EKF);
- heading: the compass's error, 1 to 2 degrees for a calibrated magnetometer (Honeywell
  HMC5883L datasheet, "1 deg to 2 deg compass heading accuracy"), a constant drawn with 2 deg rms.

The EKF's attitude noise and transient errors in manoeuvres are not modelled.
"""

from __future__ import annotations

import math

import numpy as np

from sim.autopilot.airframe import GRAVITY
from sim.autopilot.attitude_control import euler_to_matrix

HEADING_ERROR_DEG = 2.0


class AhrsError:
    """A fixed body-frame tilt error and heading error drawn at boot."""

    def __init__(self, accel_bias_body: np.ndarray, rng: np.random.Generator) -> None:
        # levelled on f + b with f = (0, 0, -g): the roll and pitch that make it look vertical
        roll = -accel_bias_body[1] / GRAVITY
        pitch = accel_bias_body[0] / GRAVITY
        self.tilt = euler_to_matrix(roll, pitch, 0.0)
        self.heading = math.radians(rng.normal(0.0, HEADING_ERROR_DEG))
        self._yaw = euler_to_matrix(0.0, 0.0, self.heading)

    def attitude(self, true_rotation: np.ndarray) -> np.ndarray:
        """The body -> NED rotation the AHRS reports for a true one."""
        return self._yaw @ true_rotation @ self.tilt
