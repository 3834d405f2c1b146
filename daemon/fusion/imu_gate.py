"""Which IMU samples the filter may integrate.

A corrupt or forged IMU message arrives with a valid CRC, and the filter integrates its
acceleration: one wrong sample becomes a velocity error its covariance does not know of. Each
stream (message type) is checked on its own:

- spike: an acceleration further from the median of the stream's last WINDOW samples than
  SPIKE_FLOOR (or SPIKE_SIGMAS robust deviations, for a noisier stream) is no motion a vehicle
  makes in one sample; a real change lasts, moves the median within half the window and passes;
- health: a stream that fails more than DROP_SHARE of its samples over DROP_WINDOW_S is dropped
  (the filter goes on without an IMU, its covariance growing instead of its estimate jumping),
  said once, until it has passed every sample for READMIT_S.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from vo.pose_optimizer import MAD_TO_SIGMA

log = logging.getLogger("sdvl.fusion")
WINDOW = 7
SPIKE_FLOOR = 20.0  # m/s^2, 2 g: beyond a filtered IMU's vibration and a step of thrust
SPIKE_SIGMAS = 6.0
DROP_WINDOW_S = 2.0
DROP_SHARE = 0.2  # a healthy stream fails almost none: vibration stays under the floor
READMIT_S = 10.0


@dataclass
class _Stream:
    """One stream's recent samples and verdicts."""

    recent: deque = field(default_factory=lambda: deque(maxlen=WINDOW))
    verdicts: deque = field(default_factory=deque)  # (t, passed) over DROP_WINDOW_S
    failed: int = 0  # verdicts that did not pass
    dropped: bool = False
    clean_since: float | None = None  # while dropped: the first of the passes in a row


class ImuGate:
    """`admit(source, t, accel)` says whether the filter may use a sample;
    `report(text)` hears when a stream is dropped or taken back."""

    def __init__(self, report: Callable[[str], None] | None = None):
        self.report = report or (lambda text: None)
        self.rejected = 0
        self._streams: dict[str, _Stream] = {}

    def admit(self, source: str, t: float, accel: np.ndarray) -> bool:
        """Whether the sample of `source` at time `t` with specific force `accel` (m/s^2) may
        be integrated."""
        s = self._streams.setdefault(source, _Stream())
        passed = not self._spike(s, accel)
        s.recent.append(accel)
        self.rejected += not passed
        return self._healthy(source, s, t, passed) and passed

    @staticmethod
    def _spike(s: _Stream, accel: np.ndarray) -> bool:
        if len(s.recent) < WINDOW // 2 + 1:
            return False
        recent = np.asarray(s.recent)
        median = np.median(recent, axis=0)
        spread = MAD_TO_SIGMA * float(np.median(np.linalg.norm(recent - median, axis=1)))
        return float(np.linalg.norm(accel - median)) > max(SPIKE_FLOOR, SPIKE_SIGMAS * spread)

    def _healthy(self, source: str, s: _Stream, t: float, passed: bool) -> bool:
        """Keep the verdicts of the last DROP_WINDOW_S; drop or take back the stream."""
        s.verdicts.append((t, passed))
        s.failed += not passed
        while s.verdicts and s.verdicts[0][0] < t - DROP_WINDOW_S:
            s.failed -= not s.verdicts.popleft()[1]
        if not s.dropped:
            if s.failed > DROP_SHARE * len(s.verdicts) and len(s.verdicts) >= WINDOW:
                s.dropped, s.clean_since = True, None
                self._say(f"IMU {source} dropped: {s.failed} of {len(s.verdicts)} samples "
                          f"inconsistent in {DROP_WINDOW_S:g} s (check the autopilot's IMU)")
            return not s.dropped
        if not passed:
            s.clean_since = None
        elif s.clean_since is None:
            s.clean_since = t
        if s.clean_since is not None and t - s.clean_since >= READMIT_S:
            s.dropped = False
            self._say(f"IMU {source} used again: consistent for {READMIT_S:g} s")
        return not s.dropped

    def _say(self, text: str) -> None:
        log.warning("fusion: %s", text)
        self.report(text)
