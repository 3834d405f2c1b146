"""How noisy the IMU stream the filter integrates really is, measured from the stream itself.

A flight controller streams one accelerometer sample per message (RAW_IMU, SCALED_IMU,
HIGHRES_IMU: ArduPilot's GCS_Common.cpp `send_raw_imu` sends the latest INS_ACCEL_FILTER-filtered
sample), 50 a second. Motor vibration, 15 m/s^2 rms on a vehicle ArduPilot calls normal
(ardupilot.org common-measuring-vibration), at the rotors' 80-200 Hz is cut by that 20 Hz
2-pole filter only to 0.2-1 m/s^2, and sampling at 50 Hz folds what is left into every sample
as broadband noise: a density of 0.03-0.15 m/s^2/sqrt(Hz), up to ten times the sensor's own and
varying with the frame, the props and the throttle. A fixed figure that fits a bench is several
times too small in flight, and the filter's dead reckoning (before the map, and between its
frames) becomes sure of positions it does not know.

A multirotor's true acceleration changes little from one 20 ms sample to the next (jerk of a
few m/s^3), so half the mean square of successive differences is the per-sample noise variance
(the first-difference estimator of white noise); times the sample interval it is the density
the filter's process noise needs.
"""

from __future__ import annotations

import bisect
from collections import deque

import numpy as np

WINDOW_S = 1.0  # follows arming and throttle within a second; 50 differences at 50 Hz
MAX_GAP_S = 0.2  # samples further apart are not successive (a gap, a stream switch)
MIN_DIFFERENCES = 10


class ImuNoise:
    """Successive-difference noise of one IMU stream over the last WINDOW_S seconds, per body
    axis (a multirotor vibrates most along its thrust axis); `density()` is at least the
    configured `floor` (m/s^2/sqrt(Hz))."""

    def __init__(self, floor: float):
        self.floor = floor
        self._last: tuple[float, np.ndarray] | None = None
        self._diffs: deque[tuple[float, np.ndarray]] = deque()  # (t, d^2 per axis)
        self._stamps: list[float] = []  # of the window's samples, sorted
        self._density: np.ndarray | None = None  # of the current window, once asked for

    def add(self, t: float, accel: np.ndarray) -> None:
        """A specific-force sample (body FRD, m/s^2) at time t, in the order fused."""
        accel = np.asarray(accel, float)
        bisect.insort(self._stamps, t)
        del self._stamps[:bisect.bisect_left(self._stamps, self._stamps[-1] - WINDOW_S)]
        self._density = None
        last, self._last = self._last, (t, accel)
        if last is None or not 0.0 < t - last[0] <= MAX_GAP_S:
            return
        self._diffs.append((t, (accel - last[1]) ** 2))
        while self._diffs and self._diffs[0][0] < t - WINDOW_S:
            self._diffs.popleft()

    def density(self) -> np.ndarray:
        """White acceleration noise density of the stream along each body axis (FRD),
        m/s^2/sqrt(Hz)."""
        if self._density is None:  # asked at every propagation, changed only by a sample
            interval = self.interval()
            if len(self._diffs) < MIN_DIFFERENCES or interval is None:
                return np.full(3, self.floor)
            variance = 0.5 * np.mean([d[1] for d in self._diffs], axis=0)  # per sample
            self._density = np.maximum(self.floor, np.sqrt(variance * interval))
        return self._density

    def interval(self) -> float | None:
        """The stream's sample interval (s): the median gap between the window's stamps in
        time order, whatever order they arrived in and with some lost; None before
        MIN_DIFFERENCES gaps."""
        gaps = np.diff(self._stamps)
        gaps = gaps[gaps > 0.0]
        return float(np.median(gaps)) if len(gaps) >= MIN_DIFFERENCES else None
