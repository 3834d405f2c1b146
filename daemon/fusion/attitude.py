"""The autopilot's attitude over the last seconds, interpolated at any time in between."""

from __future__ import annotations

import bisect

from daemon.fusion.sensors import Attitude
from daemon.fusion.state import matrix_to_rotvec, rotvec_to_matrix


class AttitudeTrack:
    """ATTITUDE samples sorted by time (arrival order does not matter), kept for `keep_s`."""

    def __init__(self, timeout_s: float, keep_s: float):
        self.timeout_s = timeout_s
        self.keep_s = keep_s
        self.times: list[float] = []
        self.samples: list[Attitude] = []

    def add(self, sample: Attitude) -> None:
        """Insert a sample in time order and forget those older than keep_s."""
        i = bisect.bisect_right(self.times, sample.t)
        self.times.insert(i, sample.t)
        self.samples.insert(i, sample)
        cut = bisect.bisect_left(self.times, self.times[-1] - self.keep_s)
        if cut:
            del self.times[:cut], self.samples[:cut]

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

