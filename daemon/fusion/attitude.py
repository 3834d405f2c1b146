"""The autopilot's attitude over the last seconds, interpolated at any time in between.

A corrupt or forged ATTITUDE arrives with a valid CRC, and the filter turns the IMU's specific
force with it: a wrong tilt leaks gravity into the acceleration. A sample is kept only when it is
within MAX_RATE_RAD_S (plus NOISE_RAD) of its nearest kept neighbour in time and its rates are
within MAX_RATE_RAD_S; STRIKES refusals in a row are a real change (a new attitude source, a
reset of the autopilot's AHRS) and the track follows it.
"""

from __future__ import annotations

import bisect

import numpy as np

from daemon.fusion.sensors import Attitude
from daemon.fusion.state import matrix_to_rotvec, rotvec_to_matrix

MAX_RATE_RAD_S = 10.0  # beyond ArduCopter's ACRO flips (ACRO_RP_RATE 360 deg/s)
NOISE_RAD = 0.02  # an AHRS's attitude noise between two samples, generously
STRIKES = 5


class AttitudeTrack:
    """ATTITUDE samples sorted by time (arrival order does not matter), kept for `keep_s`."""

    def __init__(self, timeout_s: float, keep_s: float):
        self.timeout_s = timeout_s
        self.keep_s = keep_s
        self.times: list[float] = []
        self.samples: list[Attitude] = []
        self.refused = 0
        self._strikes = 0

    def add(self, sample: Attitude) -> bool:
        """Insert a sample in time order and forget those older than keep_s; False (and not
        kept) when it cannot be the vehicle's attitude next to its neighbours."""
        if not self._plausible(sample) and self._strikes + 1 < STRIKES:
            self._strikes += 1
            self.refused += 1
            return False
        self._strikes = 0
        i = bisect.bisect_right(self.times, sample.t)
        self.times.insert(i, sample.t)
        self.samples.insert(i, sample)
        cut = bisect.bisect_left(self.times, self.times[-1] - self.keep_s)
        if cut:
            del self.times[:cut], self.samples[:cut]
        return True

    def _plausible(self, sample: Attitude) -> bool:
        if float(np.max(np.abs(sample.rates))) > MAX_RATE_RAD_S:
            return False
        i = bisect.bisect_right(self.times, sample.t)
        near = min((self.samples[j] for j in (i - 1, i) if 0 <= j < len(self.samples)),
                   key=lambda s: abs(s.t - sample.t), default=None)
        if near is None:
            return True
        turned = float(np.linalg.norm(matrix_to_rotvec(near.R_n_b.T @ sample.R_n_b)))
        return turned <= NOISE_RAD + MAX_RATE_RAD_S * abs(sample.t - near.t)

    def at(self, t: float) -> Attitude | None:
        """The attitude at time t: interpolated between neighbours, or the nearest sample
        when it is within the timeout; None when there is none close enough."""
        i = bisect.bisect_right(self.times, t)
        before = self.samples[i - 1] if i > 0 else None
        after = self.samples[i] if i < len(self.samples) else None
        if before is not None and after is not None and after.t - before.t <= 2 * self.timeout_s:
            alpha = (t - before.t) / (after.t - before.t) if after.t > before.t else 0.0
            delta = matrix_to_rotvec(before.R_n_b.T @ after.R_n_b)
            R = before.R_n_b @ rotvec_to_matrix(alpha * delta)
            rates = (1 - alpha) * before.rates + alpha * after.rates
            return Attitude(t, R, rates)
        near = min((s for s in (before, after) if s is not None),
                   key=lambda s: abs(s.t - t), default=None)
        if near is None or abs(near.t - t) > self.timeout_s:
            return None
        return near

    @property
    def latest(self) -> Attitude | None:
        """The newest sample, if any."""
        return self.samples[-1] if self.samples else None

