"""A downward rangefinder: a Benewake TFmini Plus (datasheet SJ-GU-TFmini-Plus-01 A04: 0.1-12 m
indoors, +-5 cm to 6 m and +-1 % beyond, 5 mm resolution, 100 Hz frames), set up as the ArduPilot
wiki says (common-benewake-tfmini-lidar: RNGFND1_TYPE 20, RNGFND1_MIN_CM 10, RNGFND1_MAX_CM 600
outdoors, where its range is 7 m). No echo (too far, too near) is reported as ArduPilot's
Benewake driver does: the larger of 12 m and RNGFND1_MAX_CM + 1 m
(AP_RangeFinder_Benewake.cpp, BENEWAKE_OUT_OF_RANGE_ADD)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RangefinderSpec:
    min_m: float = 0.1
    max_m: float = 7.0  # outdoors (wiki); 12 m indoors on a white target
    sigma_m: float = 0.025  # +-5 cm read as a 2-sigma bound
    sigma_fraction: float = 0.005  # +-1 % beyond 6 m, same reading
    resolution_m: float = 0.005
    period_s: float = 0.01  # 100 Hz
    model_max_m: float = 12.0

    def ardupilot_params(self) -> dict[str, float]:
        """What the wiki tells its user to set (Benewake serial, outdoors)."""
        return {"RNGFND1_TYPE": 20, "RNGFND1_MIN_CM": 10, "RNGFND1_MAX_CM": 600}


class Rangefinder:
    """`update(t, true_distance, max_param_m)` at the loop rate; `distance_m` is the driver's
    latest reading."""

    def __init__(self, spec: RangefinderSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.distance_m = spec.model_max_m
        self.in_range = False
        self._next = 0.0

    def update(self, t: float, true_distance: float, max_param_m: float) -> None:
        if t + 1e-9 < self._next:
            return
        self._next = t + self.spec.period_s
        s = self.spec
        if not np.isfinite(true_distance) or not s.min_m <= true_distance <= s.max_m:
            self.distance_m = max(s.model_max_m, max_param_m + 1.0)
            self.in_range = False
            return
        sigma = s.sigma_m if true_distance <= 6.0 else s.sigma_fraction * true_distance
        reading = true_distance + self.rng.normal(0.0, sigma)
        self.distance_m = round(reading / s.resolution_m) * s.resolution_m
        self.in_range = True
