"""Which IMU samples the filter may integrate.

A corrupt or forged IMU message arrives with a valid CRC, and the filter integrates its
acceleration: one wrong sample becomes a velocity error its covariance does not know of. Each
stream (message type) is checked on its own:

- spike: an acceleration further from the median of the stream's last WINDOW samples than
  SPIKE_FLOOR (or SPIKE_SIGMAS robust deviations, for a noisier stream) is no motion a vehicle
  makes in one sample; a real change lasts, moves the median within half the window and passes;
- jolt: a touch-down is a spike that does not last. The gear stops a 0.5 m/s descent (LAND_SPEED)
  within ~20 ms: 14-22 m/s^2 beyond g in ArduPilot's 20 Hz filtered accelerometer sampled at
  50 Hz, 27-44 at 1 m/s. Missing it, the filter keeps descending past the ground, and LAND,
  taking its climb rate from us, never detects the landing. A spike passes as a jolt when it
  pushes up along the body's z axis (the gear) by at least JOLT_MIN_ACCEL, the filter is
  descending at JOLT_MIN_DESCENT or more, and the speed it takes out is no more than that
  descent speed (plus JOLT_SPEED_MARGIN). Every jolt, spike or not, is counted (`jolts`): the
  fusion takes it for a touch-down;
- health: a stream that keeps failing (stream_health.py) is dropped, said once (the filter goes
  on without an IMU, its covariance growing instead of its estimate jumping), until it has
  passed every sample for a while.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from daemon.fusion.stream_health import StreamHealth
from vo.pose_optimizer import MAD_TO_SIGMA

WINDOW = 7
SPIKE_FLOOR = 20.0  # m/s^2, 2 g: beyond a filtered IMU's vibration and a step of thrust
SPIKE_SIGMAS = 6.0
JOLT_SPEED_MARGIN = 0.3  # m/s: the filter's own descent speed error
JOLT_MIN_ACCEL = 9.80665  # m/s^2 beyond the median: 6 sigma of a filtered IMU's vibration
JOLT_MIN_DESCENT = 0.2  # m/s: a vehicle touching down is descending
JOLT_ASIDE = 0.5  # a jolt through the gear is along body z: at most this share sideways


@dataclass
class _Stream:
    """One stream's recent samples and health."""

    recent: deque
    health: StreamHealth
    last_t: float | None = None


class ImuGate:
    """`admit(source, t, accel)` says whether the filter may use a sample;
    `report(text)` hears when a stream is dropped or taken back; `descent()` is the filter's
    descent speed now (m/s, NED z velocity), for jolts (none known: no jolt passes)."""

    def __init__(self, report: Callable[[str], None] | None = None,
                 descent: Callable[[], float] | None = None):
        self.report = report
        self.descent = descent
        self.rejected = 0
        self.jolts = 0
        self._streams: dict[str, _Stream] = {}

    def admit(self, source: str, t: float, accel: np.ndarray) -> bool:
        """Whether the sample of `source` at time `t` with specific force `accel` (m/s^2) may
        be integrated."""
        s = self._streams.get(source)
        if s is None:
            health = StreamHealth(f"IMU {source}", "dropped", "check the autopilot's IMU",
                                  self.report)
            s = self._streams[source] = _Stream(deque(maxlen=WINDOW), health)
        offset, spike = self._offset(s, accel)
        jolt = offset is not None and self._jolt(offset, t - (s.last_t or t))
        self.jolts += jolt
        passed = not spike or jolt
        s.recent.append(accel)
        s.last_t = t
        self.rejected += not passed
        return s.health.verdict(t, passed) and passed

    @staticmethod
    def _offset(s: _Stream, accel: np.ndarray) -> tuple[np.ndarray | None, bool]:
        """accel's offset from the median of the stream's recent samples (None while there are
        too few), and whether that makes it a spike."""
        if len(s.recent) < WINDOW // 2 + 1:
            return None, False
        recent = np.asarray(s.recent)
        median = np.median(recent, axis=0)
        spread = MAD_TO_SIGMA * float(np.median(np.linalg.norm(recent - median, axis=1)))
        offset = accel - median
        return offset, float(np.linalg.norm(offset)) > max(SPIKE_FLOOR, SPIKE_SIGMAS * spread)

    def _jolt(self, offset: np.ndarray, dt: float) -> bool:
        """Whether a sample's `offset` (body FRD, from the median), dt after the stream's last,
        is the gear stopping the descent: up along body z, while descending, taking out no
        more speed than the filter was descending at."""
        up = -float(offset[2])
        if self.descent is None or up < JOLT_MIN_ACCEL:
            return False
        descent = self.descent()
        along_z = float(np.linalg.norm(offset[:2])) <= JOLT_ASIDE * up
        return along_z and descent >= JOLT_MIN_DESCENT and up * dt <= descent + JOLT_SPEED_MARGIN
