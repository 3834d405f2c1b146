"""The flight controller's barometer: an MS5611 (TE Connectivity MS5611-01BA03 datasheet) read by
ArduPilot at OSR 1024 (AP_Baro_MS5611: "use an OSR of 1024 to reduce the self-heating effect"),
its conversions averaged into 20 Hz readings; the static pressure disturbed by the rotors:

- prop wash in flight lowers the pressure at the board in proportion to the rotor disc loading
  (the baro reads high): ArduPilot fits this as BARO1_THST_SCALE, published fits -100 to -200 Pa
  per unit throttle on small quads (e.g. -100 Pa at MOT_THST_HOVER 0.137: 12 % of their disc
  loading in a hover), taken here as that share of this airframe's disc loading;
- ground effect near the ground raises it (the baro reads low): ArduPilot SITL's form
  (SIM_BARO_GEFF_M, ArduPilot PR #32472) geff x (1 - height / 2 m) under thrust, with the 1 m its
  autotest uses; flight logs there range 0.4 m to 11 m, PX4-ECL #351 "typically up to 5 m".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.autopilot.airframe import AIR_DENSITY, GRAVITY


@dataclass(frozen=True)
class BaroSpec:
    noise_pa: float = 2.7  # MS5611 resolution RMS at OSR 1024 (0.027 mbar)
    conversions_per_reading: int = 4  # ~80 Hz pressure conversions averaged into 20 Hz
    period_s: float = 0.05
    prop_wash_share: float = 0.12  # of the disc loading, reads high in flight
    ground_effect_m: float = 1.0  # reads low near the ground under hover thrust
    ground_effect_height_m: float = 2.0


class Barometer:
    """Readings as altitude (m, up, relative to the NED origin's level) every period_s;
    `calibrate()` is AP_Baro's ground calibration at boot (the mean of readings there)."""

    def __init__(self, spec: BaroSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.altitude = 0.0
        self.ground = 0.0
        self._next = 0.0
        self._sigma_m = spec.noise_pa / (AIR_DENSITY * GRAVITY) / math.sqrt(
            spec.conversions_per_reading)

    def disturbance(self, height_agl: float, thrust_n: float, hover_thrust_n: float,
                    disc_area_m2: float) -> float:
        """Altitude error (m) from prop wash and ground effect at this thrust and height."""
        loading = thrust_n / disc_area_m2
        wash = self.spec.prop_wash_share * loading / (AIR_DENSITY * GRAVITY)
        ratio = thrust_n / hover_thrust_n
        ground = 0.0
        if height_agl < self.spec.ground_effect_height_m:
            ground = self.spec.ground_effect_m * ratio * \
                (1.0 - height_agl / self.spec.ground_effect_height_m)
        return wash - ground

    def update(self, t: float, true_altitude: float, disturbance: float) -> bool:
        """A new reading when one is due; True if there was."""
        if t + 1e-9 < self._next:
            return False
        self._next = t + self.spec.period_s
        self.altitude = true_altitude + disturbance + self.rng.normal(0.0, self._sigma_m)
        return True

    def calibrate(self, true_altitude: float) -> float:
        """The level the autopilot zeroes its height on: AP_Baro::calibrate averages 10
        readings with the motors stopped."""
        self.ground = true_altitude + self.rng.normal(0.0, self._sigma_m / math.sqrt(10))
        return self.ground
