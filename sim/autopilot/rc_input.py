"""The pilot's sticks as ArduCopter reads them (RCMAP defaults: 1 roll, 2 pitch, 3 throttle,
4 yaw; 1000-2000 us). Left alone they are neutral: centred, throttle at mid-stick. A ground
station moves them with RC_CHANNELS_OVERRIDE (GCS_Common.cpp handle_rc_channels_override): only
from the MAV_GCS_SYSID (SYSID_MYGCS) system, 0 releases a channel, UINT16_MAX leaves it, and an
override lapses after RC_OVERRIDE_TIME seconds without a refresh.

The conversions are Copter's: lean angles scaled to ANGLE_MAX (get_pilot_desired_lean_angles),
yaw rate to PILOT_Y_RATE, climb rate with the THR_DZ dead band around mid-stick to
PILOT_SPEED_UP/DN (get_pilot_desired_climb_rate), manual throttle with mid-stick at
MOT_THST_HOVER (get_pilot_desired_throttle).
"""

from __future__ import annotations

import math

NEUTRAL = 1500
RELEASE, IGNORE = 0, 65535


class RcInput:
    """Channels 1-4 (PWM us) with their overrides."""

    def __init__(self) -> None:
        self._override: dict[int, tuple[int, float]] = {}  # channel -> (pwm, time)

    def override(self, values: list[int], now: float) -> None:
        for channel, pwm in enumerate(values[:4], start=1):
            if pwm == IGNORE:
                continue
            if pwm == RELEASE:
                self._override.pop(channel, None)
            else:
                self._override[channel] = (int(pwm), now)

    def pwm(self, channel: int, now: float, timeout_s: float) -> int:
        pwm, t = self._override.get(channel, (NEUTRAL, now))
        return pwm if timeout_s <= 0 or now - t <= timeout_s else NEUTRAL

    def control(self, channel: int, now: float, params: object) -> float:
        """A stick in -1..1 (roll, pitch, yaw) or 0..1 (throttle)."""
        pwm = min(max(self.pwm(channel, now, params.get("RC_OVERRIDE_TIME")), 1000), 2000)
        return (pwm - 1000) / 1000.0 if channel == 3 else (pwm - NEUTRAL) / 500.0

    def lean_angles(self, now: float, params: object, angle_max: float) -> tuple[float, float]:
        """Roll and pitch (rad) the pilot asks for, limited in total to angle_max."""
        roll = self.control(1, now, params) * angle_max
        pitch = self.control(2, now, params) * angle_max  # low PWM (stick forward): nose down
        total = math.hypot(roll, pitch)
        if total > angle_max:
            roll, pitch = roll * angle_max / total, pitch * angle_max / total
        return roll, pitch

    def yaw_rate(self, now: float, params: object) -> float:
        return self.control(4, now, params) * math.radians(params.get("PILOT_Y_RATE"))

    def climb_rate(self, now: float, params: object) -> float:
        """m/s up; zero inside the dead band."""
        thr = self.control(3, now, params) * 1000.0
        dz = params.get("THR_DZ")
        up = params.get("PILOT_SPEED_UP") / 100.0
        down = (params.get("PILOT_SPEED_DN") or params.get("PILOT_SPEED_UP")) / 100.0
        if thr > 500 + dz:
            return up * (thr - 500 - dz) / (500 - dz)
        if thr < 500 - dz:
            return down * (thr - 500 + dz) / (500 - dz)
        return 0.0

    def manual_throttle(self, now: float, params: object) -> float:
        """get_pilot_desired_throttle: mid-stick gives MOT_THST_HOVER, with Copter's expo."""
        stick = self.control(3, now, params)
        hover = min(max(params.get("MOT_THST_HOVER"), 0.1), 0.9)
        expo = min(max(-(hover - 0.5) / 0.375, -0.5), 1.0)
        return stick * (1.0 - expo) + expo * stick ** 3

    def throttle_zero(self, now: float, params: object) -> bool:
        return self.control(3, now, params) <= 0.0
