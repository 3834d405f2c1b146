"""Messages that repeat a stamp: a copy, never a new measurement."""

from __future__ import annotations

from collections import deque

STAMPS_KEPT = 50  # a second's samples of a fast stream: duplicates come next to their original
RESTART_S = 1.0  # a stamp this far behind the newest is a restarted clock, not a late copy


class Repeats:
    """A message type (and sensor id) never carries one stamp twice: a second message with it
    is a copy (sent twice, or corrupt or forged), and fusing it would count one measurement
    twice. Late messages are fine: the filter replays them in order."""

    def __init__(self):
        self.count = 0
        self._stamps: dict[tuple[str, int | None], deque] = {}

    def seen(self, msg: object, remote_stamp: float) -> bool:
        """Whether `msg`'s kind already came with this stamp (the autopilot's seconds)."""
        key = (msg.get_type(), getattr(msg, "id", None))
        stamps = self._stamps.setdefault(key, deque(maxlen=STAMPS_KEPT))
        if stamps and remote_stamp < max(stamps) - RESTART_S:
            stamps.clear()  # the autopilot's clock restarted: its old stamps come again
        if remote_stamp in stamps:
            self.count += 1
            return True
        stamps.append(remote_stamp)
        return False
