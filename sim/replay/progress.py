"""The replay's progress line on stderr."""

from __future__ import annotations

import sys
import time


class Progress:
    """A one-line progress bar on stderr (a line per 10 % when stderr is not a terminal)."""

    interval_s = 0.25

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = max(total, 1), enabled
        self.tty = sys.stderr.isatty()
        self._last_decile = -1
        self._start: float | None = None

    def __len__(self) -> int:
        return self.total

    def rendered(self, done: int) -> None:
        """Frames rendered before the replay (a line per 10 %)."""
        if self.enabled and (done == self.total or done % max(self.total // 10, 1) == 0):
            print(f"  rendered {done}/{self.total} frames", file=sys.stderr, flush=True)

    def note(self, text: str) -> None:
        """One line of its own."""
        if self.enabled:
            print(text, file=sys.stderr, flush=True)

    def update(self, offered: int, processed: int, tracked: int) -> None:
        if not self.enabled:
            return
        self._start = self._start or time.monotonic()
        fraction = min(offered / self.total, 1.0)
        if not self.tty:
            decile = int(fraction * 10)
            if decile == self._last_decile:
                return
            self._last_decile = decile
        bar = "#" * int(fraction * 30)
        line = (f"replay [{bar:<30}] {offered}/{self.total} frames, processed {processed}, "
                f"tracked {tracked}, {time.monotonic() - self._start:.0f} s")
        print(("\r" + line) if self.tty else line, end="" if self.tty else "\n",
              file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.enabled and self.tty:
            print(file=sys.stderr, flush=True)
