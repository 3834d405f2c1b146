"""STATUSTEXT on state changes only, at most one per interval; changes in between merge."""

from __future__ import annotations

from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

PREFIX = "VIO: "
MAX_TEXT = 50


class StatusTexts:
    """`report(text)` sends when the text differs from the last one and the interval allows;
    otherwise the newest pending text goes out at the next `flush` that is allowed. A text the
    link could not take (not open yet) stays pending."""

    def __init__(self, interval_s: float, send: Callable[[int, str], bool]):
        self.interval_s = interval_s
        self.send = send
        self.last_text: str | None = None
        self.last_time = float("-inf")
        self.pending: tuple[int, str] | None = None
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

    def flush(self, now: float) -> None:
        """Send the pending text if the interval since the last one has passed."""
        if self.pending is None or now - self.last_time < self.interval_s:
            return
        severity, text = self.pending
        if text != self.last_text:
            if not self.send(severity, text):
                return
            self.last_text, self.last_time = text, now
        self.pending = None
