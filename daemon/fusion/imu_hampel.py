"""Each IMU stream through a Hampel filter over three samples: a sample further than FLOOR from
the median of itself and its two neighbours in time is replaced by that median.

A corrupt IMU sample with a valid CRC is a specific force the vehicle never had. The spike gate
(imu_gate.py) stops the gross ones, but a value a few m/s^2 off looks like vibration or a thrust
change and passes, and the filter integrates it as a velocity error its covariance does not
know of. The median of a sample and its neighbours removes any single wrong sample whatever its
size and passes a real step of thrust (a spike gate must hold the old value over a step until
its window follows); samples near it are kept as they are, so a clean stream's noise stays the
white noise the filter assumes (the median of three is not). Each sample is judged once its
successor is there: the filter gets the IMU one sample later, at the same instants. A sample
that arrives after later ones (reordered or delayed on the link) is judged between its
neighbours, as long as it is within the `keep_s` the filter can still replay.
"""

from __future__ import annotations

import bisect

import numpy as np

FLOOR = 1.0  # m/s^2: 20 ms of it is 2 cm/s; a filtered IMU's vibration is replaced harmlessly
MAX_GAP_S = 0.1  # samples further apart are not neighbours (the fusion's imu_timeout_s)


class _Stream:
    """A stream's samples of the last `keep_s` seconds in time order."""

    def __init__(self, keep_s: float):
        self.keep_s = keep_s
        self.times: list[float] = []
        self.accels: list[np.ndarray] = []

    def insert(self, t: float, accel: np.ndarray) -> int | None:
        """Insert a sample in time order; its index, or None when it repeats a time or is older
        than every sample kept (which are those of the last keep_s)."""
        if self.times and t - self.times[-1] > MAX_GAP_S:
            self.times, self.accels = [], []
        i = bisect.bisect_left(self.times, t)
        if (i < len(self.times) and self.times[i] == t) or (i == 0 and self.times):
            return None
        self.times.insert(i, t)
        self.accels.insert(i, accel)
        old = min(bisect.bisect_left(self.times, self.times[-1] - self.keep_s), i - 1)
        if old > 0:
            del self.times[:old], self.accels[:old]
        return i - max(old, 0)

    def judged(self, i: int) -> tuple[float, np.ndarray] | None:
        """Sample i, or the median of it and its neighbours when it is further than FLOOR
        from that; None unless both neighbours are there and near."""
        if not 0 < i < len(self.times) - 1:
            return None
        if self.times[i + 1] - self.times[i - 1] > 2 * MAX_GAP_S:
            return None
        median = np.median(self.accels[i - 1:i + 2], axis=0)
        own = self.accels[i]
        return self.times[i], median if np.linalg.norm(own - median) > FLOOR else own


class ImuHampel:
    """`push(source, t, accel)` gives the (t, specific force) to fuse that the sample lets be
    judged, or None: while a stream has fewer than three neighbouring samples, and for a sample
    older than all its stream keeps."""

    def __init__(self, keep_s: float):
        self.keep_s = keep_s
        self.late = 0
        self._streams: dict[str, _Stream] = {}

    def push(self, source: str, t: float, accel: np.ndarray) -> tuple[float, np.ndarray] | None:
        """Add a sample of `source` at time `t`; the sample it lets be judged, if any: its
        predecessor when it is the newest, else itself between its neighbours."""
        stream = self._streams.setdefault(source, _Stream(self.keep_s))
        i = stream.insert(t, np.asarray(accel, float))
        if i is None:
            self.late += 1
            return None
        newest = i == len(stream.times) - 1
        return stream.judged(i - 1 if newest else i)
