"""Each IMU stream through a running median of three samples, per axis.

A corrupt IMU sample with a valid CRC is a specific force the vehicle never had. The spike gate
(imu_gate.py) stops the gross ones, but a value a few m/s^2 off looks like vibration or a thrust
change and passes, and the filter integrates it as a velocity error its covariance does not
know of. The median of each sample and its two neighbours removes any single wrong sample
whatever its size, and passes a real step of thrust one sample later (a spike gate must hold the
old value over a step until its window follows). The median is stamped at the middle sample's
time: the filter gets the IMU one sample later, at the same instants.
"""

from __future__ import annotations

from collections import deque

import numpy as np

SPAN = 3
MAX_GAP_S = 0.1  # samples further apart are not neighbours (the fusion's imu_timeout_s)


class ImuMedian:
    """`push(source, t, accel)` gives (t, specific force) to fuse, or None while a stream has
    fewer than SPAN neighbouring samples; a sample not after its stream's newest is dropped."""

    def __init__(self):
        self.late = 0
        self._recent: dict[str, deque[tuple[float, np.ndarray]]] = {}

    def push(self, source: str, t: float, accel: np.ndarray) -> tuple[float, np.ndarray] | None:
        """Add a sample of `source` at time `t`; the median sample it completes, if any."""
        recent = self._recent.setdefault(source, deque(maxlen=SPAN))
        if recent and t <= recent[-1][0]:
            self.late += 1
            return None
        if recent and t - recent[-1][0] > MAX_GAP_S:
            recent.clear()
        recent.append((t, np.asarray(accel, float)))
        if len(recent) < SPAN:
            return None
        return recent[SPAN // 2][0], np.median([a for _, a in recent], axis=0)
