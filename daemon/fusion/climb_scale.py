"""The map's scale from a climb: least squares of the tracker's vertical motion against the
barometer's altitude change.

Without an IMU or a rangefinder the filter starts from the wide scale prior, and its first
linearised fixes land far off, so the barometer's climb then fails its gate. A straight-line fit
of -altitude = scale * z + c, with z the tracker's camera height in its own units along N's down
axis, needs no linearisation; once the fitted climb reaches `climb_scale_min_m` it gives the
scale, with a std from the barometer's noise or the fit's residuals over the climb's spread
(map_fusion pairs readings only above the ground effect, baro_ground_effect_height_m).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

KEPT = 3000  # pairs (5 min of a 10 Hz barometer): a take-off climb is far shorter


@dataclass
class ClimbScale:
    """Pairs (tracker down coordinate in map units, barometric altitude in metres) of one map
    segment, one per barometer reading."""

    z_units: list[float] = field(default_factory=list)
    altitude: list[float] = field(default_factory=list)
    baro_t: float = float("-inf")  # time of the last reading paired

    def copy(self) -> ClimbScale:
        """An independent copy (the filter's snapshots)."""
        return ClimbScale(list(self.z_units), list(self.altitude), self.baro_t)

    def add(self, z_units: float, baro_t: float, altitude: float) -> None:
        """The reading at `baro_t` with the tracker's height at a frame next to it; a reading
        already paired, and non-finite values, are ignored."""
        if baro_t > self.baro_t and np.isfinite(z_units) and np.isfinite(altitude):
            self.baro_t = baro_t
            self.z_units.append(float(z_units))
            self.altitude.append(float(altitude))
            if len(self.z_units) > KEPT:  # a map that never converges must not grow without end
                del self.z_units[0], self.altitude[0]

    def climb_m(self, log_scale: float) -> float:
        """The tracker's height range in metres at scale exp(log_scale)."""
        return float(np.exp(log_scale) * np.ptp(self.z_units)) if self.z_units else 0.0

    def fit(self, min_climb_m: float, baro_std_m: float) -> tuple[float, float] | None:
        """(ln(scale), its std) once the climb reaches `min_climb_m` and the fit says the map
        goes down when the barometer goes up; else None. The std is the larger of the
        barometer's noise and the fit's residuals, over the tracker's spread of heights."""
        if len(self.z_units) < 3:
            return None
        z = np.asarray(self.z_units)
        down = -np.asarray(self.altitude)
        dz = z - z.mean()
        spread = float(dz @ dz)
        if spread <= 0:
            return None
        slope = float(dz @ (down - down.mean())) / spread
        if not (slope > 0 and slope * float(np.ptp(z)) >= min_climb_m):  # the fitted climb
            return None
        residual = down - down.mean() - slope * dz
        noise = max(baro_std_m, float(np.sqrt(residual @ residual / (len(z) - 2))))
        return float(np.log(slope)), noise / (slope * np.sqrt(spread))
