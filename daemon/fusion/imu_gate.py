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
  pushes up along the body's z axis (the gear) and the speed it takes out is no more than the
  filter's descent speed then (plus JOLT_SPEED_MARGIN);
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
        self._streams: dict[str, _Stream] = {}

    def admit(self, source: str, t: float, accel: np.ndarray) -> bool:
        """Whether the sample of `source` at time `t` with specific force `accel` (m/s^2) may
        be integrated."""
        s = self._streams.get(source)
        if s is None:
            health = StreamHealth(f"IMU {source}", "dropped", "check the autopilot's IMU",
                                  self.report)
            s = self._streams[source] = _Stream(deque(maxlen=WINDOW), health)
        offset = self._spike(s, accel)
        passed = offset is None or self._jolt(offset, t - (s.last_t or t))
        s.recent.append(accel)
        s.last_t = t
        self.rejected += not passed
        return s.health.verdict(t, passed) and passed

    @staticmethod
    def _spike(s: _Stream, accel: np.ndarray) -> np.ndarray | None:
        """accel's offset from the median of the stream's recent samples when it is a spike,
        else None."""
        if len(s.recent) < WINDOW // 2 + 1:
            return None
        recent = np.asarray(s.recent)
        median = np.median(recent, axis=0)
        spread = MAD_TO_SIGMA * float(np.median(np.linalg.norm(recent - median, axis=1)))
        offset = accel - median
        limit = max(SPIKE_FLOOR, SPIKE_SIGMAS * spread)
        return offset if float(np.linalg.norm(offset)) > limit else None

    def _jolt(self, offset: np.ndarray, dt: float) -> bool:
        """Whether a spike `offset` (body FRD, from the median) of a sample dt after the
        stream's last is the gear stopping the descent: up along body z, taking out no more
        speed than the filter was descending at."""
        if self.descent is None or offset[2] >= 0.0:
            return False
        up = -float(offset[2])
        along_z = float(np.linalg.norm(offset[:2])) <= JOLT_ASIDE * up
        return along_z and up * dt <= self.descent() + JOLT_SPEED_MARGIN
