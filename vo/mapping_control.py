"""How the tracker has its mapper's steps run (thesis 6.1: mapping beside tracking): right after
each frame (`InlineMapping`, sequential and reproducible), or queued in a bounded backlog that a
mapping thread (vo.mapping_thread) or the caller (vo.stepped_mapping, a test hook) works off.
No tracked frame is dropped from mapping: tracking waits for room in the backlog instead (a live
service skips frames meanwhile)."""

from __future__ import annotations

import threading
from collections import deque

from vo.frame import Frame
from vo.mapping import Mapper


class MappingBacklog:
    """Tracked frames waiting for their mapping step, oldest first, and the one being mapped
    (by the mapping thread, or by the caller with stepped mapping). It holds `size` frames:
    tracking starts a frame only while there is room."""

    def __init__(self, size: int):
        self.size = size
        self._items: deque = deque()
        self._busy = False
        self._cond = threading.Condition()

    def __len__(self) -> int:
        """Frames tracked and not mapped yet (waiting or being mapped)."""
        with self._cond:
            return self._unmapped()

    def _unmapped(self) -> int:
        return len(self._items) + int(self._busy)

    def waiting(self) -> int:
        """Frames waiting, not counting the one being mapped."""
        with self._cond:
            return len(self._items)

    def has_room(self) -> bool:
        """True while fewer than `size` frames are unmapped."""
        return len(self) < self.size

    def wait_for_room(self, timeout: float | None = None) -> bool:
        """Block until has_room (at most timeout seconds); whether it has."""
        with self._cond:
            return self._cond.wait_for(lambda: self._unmapped() < self.size, timeout)

    def put(self, item) -> None:
        """Append an item (None stops the mapping thread)."""
        with self._cond:
            self._items.append(item)
            self._cond.notify_all()

    def take(self):
        """The oldest item (waiting for one), marked as being mapped until done()."""
        with self._cond:
            self._cond.wait_for(lambda: self._items)
            self._busy = True
            return self._items.popleft()

    def done(self) -> None:
        """The item taken last is mapped."""
        with self._cond:
            self._busy = False
            self._cond.notify_all()


class InlineMapping:
    """Each tracked frame's mapping step runs at once, in the tracking thread."""

    backlog: MappingBacklog | None = None

    def __init__(self):
        self.mapper: Mapper | None = None

    def attach(self, mapper: Mapper) -> None:
        """Run the steps of a new map's mapper from now on (call stop() for the old one)."""
        self.mapper = mapper

    def stop(self) -> None:
        """No more steps of the current mapper."""

    def before_frame(self) -> None:
        """Called before a frame is tracked: make room for its mapping step."""

    def frame_tracked(self) -> None:
        """Called once a frame is tracked (its mapping step not submitted yet)."""

    def unmapped(self) -> int:
        """Tracked frames whose mapping step has not run yet."""
        return 0

    def submit(self, frame: Frame, keyframe: bool) -> None:
        """Map a tracked frame (make it a keyframe when asked)."""
        self.mapper.step(frame, keyframe)

    def wait_for_room(self, timeout: float | None = None) -> bool:
        """Whether another frame may be tracked now (queued mapping: waiting at most
        timeout seconds for room)."""
        return True


class QueuedMapping(InlineMapping):
    """Tracked frames wait in a bounded backlog for their mapping step; a local BA runs only
    while none waits."""

    def __init__(self, queue_size: int):
        super().__init__()
        self.queue_size = queue_size

    def attach(self, mapper: Mapper) -> None:
        self.backlog = MappingBacklog(self.queue_size)
        mapper.ba_allowed = lambda: self.backlog.waiting() == 0
        super().attach(mapper)

    def unmapped(self) -> int:
        return len(self.backlog)

    def submit(self, frame: Frame, keyframe: bool) -> None:
        self.backlog.put((frame, keyframe))  # never dropped: before_frame waits for room

    def wait_for_room(self, timeout: float | None = None) -> bool:
        return self.backlog.has_room()
