"""ArduCopter's motor output for a quad X (libraries/AP_Motors: AP_MotorsMatrix QUAD X factors
and output_armed_stabilizing, AP_MotorsMulticopter spool states and thrust linearisation,
AP_Motors_Thrust_Linearization):

- roll and pitch factors cos(angle + 90 deg) and cos(angle) of each motor's arm angle, yaw +-1
  by spin direction, each set normalised to 0.5;
- roll and pitch are kept first: when motors would leave 0..1 the yaw is cut to what fits, then
  the throttle moved, then roll/pitch scaled; the limit flags tell the controllers' integrators;
- a thrust demand becomes an actuator value through the inverse of the MOT_THST_EXPO curve,
  mapped between MOT_SPIN_MIN and MOT_SPIN_MAX; disarmed the motors stop, armed on the ground
  they idle at MOT_SPIN_ARM, and they take MOT_SPOOL_TIME to spool up to flight.

Output commands are 0..1 between MOT_SPIN_MIN and MOT_SPIN_MAX (what the physics spins); the
idle spin below MOT_SPIN_MIN makes no thrust, as in ArduPilot SITL's pwm_to_command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

ARM_ANGLES_DEG = (45.0, -135.0, -45.0, 135.0)  # QUAD X, ArduPilot's motor order
YAW_FACTORS = (1.0, 1.0, -1.0, -1.0)  # CCW, CCW, CW, CW


class Spool(Enum):
    """AP_Motors::SpoolState."""

    SHUT_DOWN = "shut down"
    GROUND_IDLE = "ground idle"
    SPOOLING_UP = "spooling up"
    THROTTLE_UNLIMITED = "throttle unlimited"
    SPOOLING_DOWN = "spooling down"


@dataclass
class Limits:
    """AP_Motors::limit: which outputs saturated on the last mix."""

    roll: bool = False
    pitch: bool = False
    yaw: bool = False
    throttle_lower: bool = True
    throttle_upper: bool = False


def _normalised(factors: np.ndarray) -> np.ndarray:
    return 0.5 * factors / np.abs(factors).max()


@dataclass
class Motors:
    """The mixer and spool state machine; `output(...)` gives the four motor commands."""

    spool: Spool = Spool.SHUT_DOWN
    desired: Spool = Spool.SHUT_DOWN
    ramp: float = 0.0  # 0 at ground idle .. 1 spooled up
    limit: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        angles = np.radians(ARM_ANGLES_DEG)
        self.roll_f = _normalised(np.cos(angles + math.pi / 2))
        self.pitch_f = _normalised(np.cos(angles))
        self.yaw_f = _normalised(np.array(YAW_FACTORS))

    def update_spool(self, armed: bool, dt: float, spool_time: float) -> None:
        """Move the spool state towards the desired one (output_logic)."""
        if not armed:
            self.spool, self.ramp = Spool.SHUT_DOWN, 0.0
            return
        rate = dt / max(spool_time, 0.05)
        if self.desired is Spool.THROTTLE_UNLIMITED:
            self.ramp = min(self.ramp + rate, 1.0)
            self.spool = Spool.THROTTLE_UNLIMITED if self.ramp >= 1.0 else Spool.SPOOLING_UP
        elif self.desired is Spool.GROUND_IDLE:
            self.ramp = max(self.ramp - rate, 0.0)
            self.spool = Spool.GROUND_IDLE if self.ramp <= 0.0 else Spool.SPOOLING_DOWN
        else:
            self.spool, self.ramp = Spool.SHUT_DOWN, 0.0

    def output(self, roll: float, pitch: float, yaw: float, throttle: float,
               params: object) -> np.ndarray:
        """Motor commands (4, 0..1) for roll/pitch/yaw demands (-1..1) and a throttle
        (thrust fraction 0..1), as the spool state allows."""
        if self.spool is Spool.SHUT_DOWN or self.spool is Spool.GROUND_IDLE:
            self.limit = Limits(True, True, True, True, False)
            return np.zeros(4)
        thrust = self._mix(roll, pitch, yaw, throttle * self.ramp, params)  # ramps in spool-up
        return thrust_to_command(thrust, params.get("MOT_THST_EXPO"))

    def _mix(self, roll: float, pitch: float, yaw: float, throttle: float,
             params: object) -> np.ndarray:
        """output_armed_stabilizing: thrust demand (0..1) per motor."""
        limit = Limits(throttle_lower=False)
        throttle_min = params.get("ATC_THR_MIX_MIN") * params.get("MOT_THST_HOVER")
        if throttle <= throttle_min:
            throttle, limit.throttle_lower = throttle_min, True
        if throttle >= 1.0:
            throttle, limit.throttle_upper = 1.0, True
        rp = roll * self.roll_f + pitch * self.pitch_f
        headroom = params.get("MOT_YAW_HEADROOM") / 1000.0
        room = max(min(1.0 - rp.max() - throttle, throttle + rp.min()), headroom * 0.5)
        yaw_thrust = yaw * self.yaw_f
        if np.abs(yaw_thrust).max() > room:
            yaw_thrust *= room / np.abs(yaw_thrust).max()
            limit.yaw = True
        rpy = rp + yaw_thrust
        spread = rpy.max() - rpy.min()
        if spread > 1.0:
            rpy = rpy / spread
            limit.roll = limit.pitch = True
        low, high = -rpy.min(), 1.0 - rpy.max()
        if throttle < low:
            throttle, limit.throttle_lower = low, True
        elif throttle > high:
            throttle, limit.throttle_upper = high, True
        self.limit = limit
        return np.clip(throttle + rpy, 0.0, 1.0)


def thrust_to_command(thrust: np.ndarray, expo: float) -> np.ndarray:
    """Inverse of the thrust curve (1 - e) c + e c^2 (AP_Motors_Thrust_Linearization
    apply_thrust_curve_and_volt_scaling, battery compensation left out)."""
    thrust = np.clip(thrust, 0.0, 1.0)
    if expo <= 0:
        return thrust
    return ((expo - 1.0) + np.sqrt((1.0 - expo) ** 2 + 4.0 * expo * thrust)) / (2.0 * expo)
