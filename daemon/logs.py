"""Log lines that never stop the service: when stderr cannot be written (a file on a full disk,
a closed pipe) a line is dropped and counted instead of raising or printing a traceback, and the
next line that gets through says how many were lost. Under systemd stderr is the journal's
stream socket, which journald itself rate-limits and drops from; this covers the rest.
"""

from __future__ import annotations

import logging
import sys

FORMAT = "%(levelname)s %(name)s: %(message)s"


class DroppingHandler(logging.StreamHandler):
    """A StreamHandler that counts the records its stream refused (`dropped`)."""

    def __init__(self, stream: object = None):
        super().__init__(stream if stream is not None else sys.stderr)
        self.dropped = 0  # since the last line that got through
        self.dropped_total = 0

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = self.format(record) + self.terminator
            if self.dropped:
                text = (f"WARNING sdvl.logs: {self.dropped} log line(s) could not be written "
                        f"(disk full?)" + self.terminator + text)
            self.stream.write(text)
            self.flush()
            self.dropped = 0
        except RecursionError:
            raise
        except Exception:
            self.dropped += 1
            self.dropped_total += 1


def setup(level: str, stream: object = None) -> DroppingHandler:
    """One line per event on stderr (journald adds the time and unit); returns the handler."""
    handler = DroppingHandler(stream)
    handler.setFormatter(logging.Formatter(FORMAT))
    logging.basicConfig(level=level.upper(), handlers=[handler], force=True)
    return handler


def dropped_total() -> int:
    """Log lines lost so far (for the systemd status line)."""
    return sum(h.dropped_total for h in logging.getLogger().handlers
               if isinstance(h, DroppingHandler))
