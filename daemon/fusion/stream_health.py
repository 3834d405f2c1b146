"""Whether an autopilot stream keeps passing its checks: a source that keeps failing is said
once (log and STATUSTEXT) and, for the IMU, dropped until it is consistent again.

Each sample's verdict is kept for WINDOW_S: failing more than SHARE of them (with at least
MIN_SAMPLES seen) makes the stream unhealthy; passing every sample for READMIT_S makes it
healthy again. A healthy stream fails almost none: vibration, noise and the autopilot's own
filtering stay inside every check.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable

log = logging.getLogger("sdvl.fusion")
WINDOW_S = 2.0
SHARE = 0.2
MIN_SAMPLES = 7
READMIT_S = 10.0


class StreamHealth:
    """The verdicts of one stream's checks; `verdict(t, passed)` says whether it is healthy.
    `label` names it in what is said (e.g. "IMU SCALED_IMU"), `failing` what happens to it
    ("dropped"), `advice` what a user should check."""

    def __init__(self, label: str, failing: str, advice: str,
                 say: Callable[[str], None] | None = None):
        self.label, self.failing, self.advice = label, failing, advice
        self.say = say or (lambda text: None)
        self.healthy = True
        self._verdicts: deque[tuple[float, bool]] = deque()  # (t, passed) over WINDOW_S
        self._failed = 0
        self._clean_since: float | None = None  # while unhealthy: the first pass in a row

    def verdict(self, t: float, passed: bool) -> bool:
        """Record the check of the sample at time t; True while the stream is healthy."""
        self._verdicts.append((t, passed))
        self._failed += not passed
        while self._verdicts and self._verdicts[0][0] < t - WINDOW_S:
            self._failed -= not self._verdicts.popleft()[1]
        if self.healthy:
            if self._failed > SHARE * len(self._verdicts) and len(self._verdicts) >= MIN_SAMPLES:
                self.healthy, self._clean_since = False, None
                self._tell(f"{self.label} {self.failing}: {self._failed} of "
                           f"{len(self._verdicts)} samples inconsistent in {WINDOW_S:g} s "
                           f"({self.advice})")
            return self.healthy
        if not passed:
            self._clean_since = None
        elif self._clean_since is None:
            self._clean_since = t
        if self._clean_since is not None and t - self._clean_since >= READMIT_S:
            self.healthy = True
            self._tell(f"{self.label} used again: consistent for {READMIT_S:g} s")
        return self.healthy

    def _tell(self, text: str) -> None:
        log.warning("fusion: %s", text)
        self.say(text)
