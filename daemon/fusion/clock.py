"""Autopilot time -> our CLOCK_MONOTONIC seconds.

The offset (ours minus the autopilot's boot time) comes from TIMESYNC when the service measures
it (`set_offset`); until then it is estimated much like ArduPilot's jitter correction does: the
least (arrival - remote stamp) over a sliding window belongs to the least delayed messages, so
it is the true offset plus only the smallest transport latency. Not the very least: a message
that arrives before it can have been sent (a corrupt stamp a little ahead, a packet the link
reordered or replayed) would drag the estimate early and every stamp with it, so the estimate
is the QUANTILE of the window's delays, which such messages cannot move while they are fewer
than that (a fuzz that reordered 4 % of the packets moved the 2 % quantile 31 ms, the 10 %
one 9 ms). What the estimate is off by, a few milliseconds of latency, the filter finds as its
TIME_OFFSET (state.py); what it cannot follow is the estimate jumping about. A stamp more
than a second behind the estimate (a corrupt or very late message) or more than 50 ms ahead of
it (a corrupt stamp) is dropped; several such in a row mean the autopilot's clock changed (a
reboot) and restart the estimate. Stamps in UNIX time (some time_usec fields) get their own
offset.
"""

from __future__ import annotations

import bisect
from collections import deque

UNIX_EPOCH_THRESHOLD_S = 1e9  # no autopilot has been up for 31 years: such stamps are UNIX time
JUMP_S = 1.0
EARLY_S = 0.05  # arriving this much earlier than the best so far: a wrong stamp, or a new clock
STRIKES_TO_RESTART = 5
MAX_AHEAD_S = 0.05  # a stamp mapped this far after its own arrival is wrong
QUANTILE = 0.1  # of the delays: below it, messages that came too early to be right


class _Domain:
    """Offset estimate for one remote clock."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self.samples: deque[tuple[float, float]] = deque()  # (arrival, arrival - remote)
        self.delays: list[float] = []  # the same delays, sorted
        self.strikes = 0

    def observe(self, remote: float, arrival: float) -> bool:
        delay = arrival - remote
        current = self.offset()
        if current is not None and not -EARLY_S <= delay - current <= JUMP_S:
            self.strikes += 1
            if self.strikes < STRIKES_TO_RESTART:
                return False
            self.samples.clear()
            self.delays.clear()
        self.strikes = 0
        self.samples.append((arrival, delay))
        bisect.insort(self.delays, delay)
        while self.samples[0][0] < arrival - self.window_s:
            _, old = self.samples.popleft()
            del self.delays[bisect.bisect_left(self.delays, old)]
        return True

    def offset(self) -> float | None:
        if not self.delays:
            return None
        return self.delays[int(QUANTILE * (len(self.delays) - 1))]


class ClockMap:
    """Maps autopilot stamps (seconds) to our monotonic seconds."""

    def __init__(self, window_s: float = 10.0):
        self._boot = _Domain(window_s)
        self._unix = _Domain(window_s)
        self._timesync_offset: float | None = None

    def set_offset(self, offset_s: float | None) -> None:
        """Use a TIMESYNC-measured offset (ours - autopilot boot time, seconds) for boot-time
        stamps; None returns to the arrival-time estimate."""
        self._timesync_offset = offset_s

    def to_local(self, remote: float, arrival: float) -> float | None:
        """Our monotonic time of a message stamped `remote` that arrived at our `arrival`;
        None when the stamp cannot be right."""
        domain = self._unix if remote > UNIX_EPOCH_THRESHOLD_S else self._boot
        consistent = domain.observe(remote, arrival)
        if domain is self._boot and self._timesync_offset is not None:
            local = remote + self._timesync_offset
            ok = arrival - JUMP_S <= local <= arrival + MAX_AHEAD_S
            return local if ok else None
        return remote + domain.offset() if consistent else None
