"""Which stream of one kind (IMU, barometer) the filter fuses when the autopilot sends several.

The first stream seen is fused at once. A stream is a candidate once it streams steadily: at
least STEADY_SAMPLES samples within the last WINDOW_S seconds and the newest no older than
MAX_GAP_S. The stream fused is kept while it is steady; a preferred steady stream (lower
priority number, sensors.py) replaces it, and when it is not steady the best steady one takes
over. A stray message (a corrupt packet, another stream's single
sample) is never steady, so it cannot take the filter away from the stream that is.
"""

from __future__ import annotations

import logging
from collections import deque

log = logging.getLogger("sdvl.fusion")
WINDOW_S = 2.0
STEADY_SAMPLES = 5  # in WINDOW_S: 2.5 Hz, below any IMU or barometer stream an autopilot sends
MAX_GAP_S = 1.0


class SourceChoice:
    """Feed each sample's source and time to `offer`; it says whether to fuse the sample."""

    def __init__(self, kind: str, priority: dict[str, int]):
        self.kind = kind
        self.priority = priority
        self.current: str | None = None
        self.switches = 0
        self._times: dict[str, deque[float]] = {}
        self._now = float("-inf")

    def offer(self, source: str, t: float) -> bool:
        """Record a sample of `source` at time `t` (seconds); True when it is to be fused."""
        self._now = max(self._now, t)
        times = self._times.setdefault(source, deque())
        times.append(t)
        while times and times[0] < self._now - WINDOW_S:
            times.popleft()
        if self.current is None and source in self.priority:
            self._switch(source, "first stream")  # no waiting: a stray one is replaced below
        elif source != self.current:
            self._reconsider()
        return source == self.current

    def steady(self, source: str) -> bool:
        """Whether `source` has been streaming steadily up to the newest sample of this kind."""
        times = self._times.get(source)
        recent = [t for t in times or () if t >= self._now - WINDOW_S]
        return len(recent) >= STEADY_SAMPLES and self._now - max(recent) <= MAX_GAP_S

    def _reconsider(self) -> None:
        """Switch to the preferred steady stream when the current one is not it."""
        steady = [s for s in self._times if s in self.priority and self.steady(s)]
        if not steady:
            return
        best = min(steady, key=self.priority.__getitem__)
        current_ok = self.current is not None and self.steady(self.current)
        if current_ok and self.priority[best] >= self.priority[self.current]:
            return
        self._switch(best, "preferred" if current_ok else f"{self.current} not steady")

    def _switch(self, source: str, why: str) -> None:
        log.info("fusion: %s from %s (%s)", self.kind, source, why)
        self.current = source
        self.switches += 1
