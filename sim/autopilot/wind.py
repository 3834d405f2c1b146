"""Seeded wind for the simulated multicopter: a steady wind plus gusts, each axis a first-order
Gauss-Markov process (the form of the Dryden model's low-altitude gusts, MIL-F-8785C; ArduPilot
SITL offers the same knobs as SIM_WIND_SPD, SIM_WIND_DIR and SIM_WIND_TURB). Off unless a
`Wind` is given."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Wind:
    """Steady wind blowing FROM `from_deg` (compass) at `speed_ms`, gusts of `gust_ms` rms per
    horizontal axis (a third of it vertically) with correlation time `gust_tau_s`."""

    speed_ms: float = 0.0
    from_deg: float = 0.0
    gust_ms: float = 0.0
    gust_tau_s: float = 2.0
    seed: int = 0


class WindField:
    """The air's velocity (NED, m/s) over time, advanced with `step(dt)`."""

    def __init__(self, wind: Wind | None) -> None:
        self.wind = wind or Wind()
        self.rng = np.random.default_rng(self.wind.seed)
        towards = np.radians(self.wind.from_deg + 180.0)
        self.mean = self.wind.speed_ms * np.array([np.cos(towards), np.sin(towards), 0.0])
        self.sigma = self.wind.gust_ms * np.array([1.0, 1.0, 1.0 / 3.0])
        self.gust = np.zeros(3)
        self.velocity = self.mean.copy()

    def step(self, dt: float) -> np.ndarray:
        if self.wind.gust_ms > 0:
            decay = np.exp(-dt / self.wind.gust_tau_s)
            self.gust = self.gust * decay + self.sigma * np.sqrt(1.0 - decay * decay) * \
                self.rng.standard_normal(3)
            self.velocity = self.mean + self.gust
        return self.velocity
