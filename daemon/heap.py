"""Memory the C allocator keeps after the service freed it goes back to the system.

glibc's malloc keeps freed blocks in its arenas for reuse and returns them only from the top of
an arena. The service's threads allocate and free frames, pyramids and whole maps (a map is
thrown away when tracking is lost), so the holes between blocks still in use only add up: in a
starved soak the arenas held 72 -> 157 MB free in 20 minutes while what was in use stayed at
125-200 MB, and the resident memory grew with the holes (RESULTS.md: faults-soak).
`malloc_trim(0)` hands the free pages of every arena back; other C libraries have no such call
and nothing is done.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable

TRIM_INTERVAL_S = 10.0  # a trim walks the arenas' free lists: a few ms


def malloc_trim() -> Callable[[int], int] | None:
    """glibc's malloc_trim, or None when the process's C library has none."""
    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None


class HeapTrim:
    """Trims the heap every `interval_s` seconds: `due(now)` says when, `trim_now()` does it
    (off the event loop: a trim holds the allocator's locks for a few ms, up to ~90 ms
    measured on a starved CPU)."""

    def __init__(self, interval_s: float = TRIM_INTERVAL_S,
                 trim: Callable[[int], int] | None = None):
        self.interval_s = interval_s
        self.trim = trim or malloc_trim()
        self.trims = 0
        self._due = -math.inf

    def due(self, now: float) -> bool:
        """Whether a trim is due at `now` (monotonic seconds); the next one is then
        `interval_s` later."""
        if self.trim is None or now < self._due:
            return False
        self._due = now + self.interval_s
        return True

    def trim_now(self) -> None:
        """Hand the free pages of every arena back to the system."""
        self.trim(0)
        self.trims += 1
