"""Which IMU samples the filter may integrate.

A corrupt or forged IMU message arrives with a valid CRC, and the filter integrates its
acceleration: one wrong sample becomes a velocity error its covariance does not know of. Each
stream (message type) is checked on its own:

- spike: an acceleration further from the median of the stream's last WINDOW samples than
  SPIKE_FLOOR (or SPIKE_SIGMAS robust deviations, for a noisier stream) is no motion a vehicle
  makes in one sample; a real change lasts, moves the median within half the window and passes;
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


@dataclass
class _Stream:
    """One stream's recent samples and health."""

    recent: deque
    health: StreamHealth


class ImuGate:
    """`admit(source, t, accel)` says whether the filter may use a sample;
    `report(text)` hears when a stream is dropped or taken back."""

    def __init__(self, report: Callable[[str], None] | None = None):
        self.report = report
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
        passed = not self._spike(s, accel)
        s.recent.append(accel)
        self.rejected += not passed
        return s.health.verdict(t, passed) and passed

    @staticmethod
    def _spike(s: _Stream, accel: np.ndarray) -> bool:
        if len(s.recent) < WINDOW // 2 + 1:
            return False
        recent = np.asarray(s.recent)
        median = np.median(recent, axis=0)
        spread = MAD_TO_SIGMA * float(np.median(np.linalg.norm(recent - median, axis=1)))
        return float(np.linalg.norm(accel - median)) > max(SPIKE_FLOOR, SPIKE_SIGMAS * spread)
