"""STATUSTEXT on state changes only, at most one per interval; changes in between merge."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

PREFIX = "VIO: "
MAX_TEXT = 50
MAX_NOTICES = 8


class StatusTexts:
    """`report(text)` sends when the text differs from the last one and the interval allows;
    otherwise the newest pending text goes out at the next `flush` that is allowed. A text the
    link could not take (not open yet) stays pending. `notice(text)` is an event, not a state:
    it is never merged away but queued (at most MAX_NOTICES) and sent before the pending
    state, one per interval."""

    def __init__(self, interval_s: float, send: Callable[[int, str], bool]):
        self.interval_s = interval_s
        self.send = send
        self.last_text: str | None = None
        self.last_time = float("-inf")
        self.pending: tuple[int, str] | None = None
        self.notices: deque[tuple[int, str]] = deque(maxlen=MAX_NOTICES)
        self.merged = 0

    def report(self, text: str, now: float,
               severity: int = mavlink2.MAV_SEVERITY_INFO) -> None:
        """Queue a state-change text (prefixed 'VIO: ', cut to 50 characters)."""
        text = (PREFIX + text)[:MAX_TEXT]
        if self.pending is not None:
            self.merged += 1
        elif text == self.last_text:
            return
        self.pending = (severity, text)
        self.flush(now)

    def notice(self, text: str, now: float,
               severity: int = mavlink2.MAV_SEVERITY_WARNING) -> None:
        """Queue an event text (prefixed 'VIO: ', cut to 50 characters)."""
        self.notices.append((severity, (PREFIX + text)[:MAX_TEXT]))
        self.flush(now)

    def flush(self, now: float) -> None:
        """Send a queued notice, else the pending text, if the interval has passed."""
        if now - self.last_time < self.interval_s:
            return
        if self.notices:
            severity, text = self.notices[0]
            if self.send(severity, text):
                self.notices.popleft()
                self.last_text, self.last_time = text, now
            return
        if self.pending is None:
            return
        severity, text = self.pending
        if text != self.last_text:
            if not self.send(severity, text):
                return
            self.last_text, self.last_time = text, now
        self.pending = None
