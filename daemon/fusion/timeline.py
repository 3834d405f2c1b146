"""Events in time order, with filter snapshots so that a late event can still be fused.

Sensor samples and tracker frames become events stamped on our clock. Events wait in `pending`
until a frame arrives; then everything up to the frame's time is applied in time order. An event
older than the filter's time (it arrived late) rewinds the filter to the last snapshot before it
and replays the applied events since, if that snapshot is still kept (`history_s`); otherwise it
is dropped and counted.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

FUTURE_LIMIT_S = 5.0  # events stamped further ahead of the newest frame are wrong
# events at one time are applied in this order whatever order they arrived in (the sensors
# first, the frame that uses them last); same kinds keep their arrival order
KIND_ORDER = {"attitude": 0, "imu": 1, "touchdown": 2, "baro": 3, "range": 4, "frame": 5}


@dataclass(order=True)
class Event:
    """Something that happened at time t."""

    t: float
    rank: int
    seq: int
    kind: str = field(compare=False)
    data: object = field(compare=False)


class Timeline:
    """Pending events, applied events and snapshots taken after each frame."""

    def __init__(self, history_s: float):
        self.history_s = history_s
        self.pending: list[Event] = []
        self.applied: list[Event] = []
        self.snapshots: list[tuple[float, object]] = []  # (time, snapshot), increasing time
        self.replays = 0
        self.dropped_late = 0
        self._seq = itertools.count()

    def add(self, t: float, kind: str, data: object) -> None:
        """Queue an event of `kind` at time t."""
        bisect.insort(self.pending, Event(t, KIND_ORDER.get(kind, len(KIND_ORDER)),
                                          next(self._seq), kind, data))

    def run(self, until: float, now_t: float | None, apply: Callable[[Event], None],
            restore: Callable[[object], None], snapshot: Callable[[], object]) -> None:
        """Apply pending events up to time `until` (the filter is at `now_t`), rewinding first
        if some are older than the filter."""
        self.pending = [e for e in self.pending if e.t <= until + FUTURE_LIMIT_S]
        late = [e for e in self.pending if now_t is not None and e.t < now_t]
        if late:
            self._rewind(late[0].t, now_t, restore)
        while self.pending and self.pending[0].t <= until:
            event = self.pending.pop(0)
            apply(event)
            self.applied.append(event)
            if event.kind == "frame":
                self.snapshots.append((event.t, snapshot()))
        self._prune(until)

    def _rewind(self, t: float, now_t: float, restore: Callable[[object], None]) -> None:
        i = bisect.bisect_right([s for s, _ in self.snapshots], t)
        if i == 0:
            too_old = [e for e in self.pending if e.t < now_t]
            self.dropped_late += len(too_old)
            self.pending = [e for e in self.pending if e.t >= now_t]
            return
        snap_t, snap = self.snapshots[i - 1]
        del self.snapshots[i:]
        restore(snap)
        keep = bisect.bisect_right([e.t for e in self.applied], snap_t)
        for event in self.applied[keep:]:
            bisect.insort(self.pending, event)
        del self.applied[keep:]
        self.replays += 1

    def _prune(self, until: float) -> None:
        cut = bisect.bisect_left([s for s, _ in self.snapshots], until - self.history_s)
        del self.snapshots[:min(cut, len(self.snapshots) - 1)]
        oldest = self.snapshots[0][0] if self.snapshots else until
        keep = bisect.bisect_left([e.t for e in self.applied], oldest)
        del self.applied[:keep]
