"""Mapping in its own thread: tracked frames queue in a bounded backlog and the thread runs
their mapping steps in order. A local BA in that thread pauses while a frame is tracked, and an
error in it is raised in the tracking thread at the next frame."""

from __future__ import annotations

import threading

from vo.mapping import Mapper
from vo.mapping_control import QueuedMapping

# a local BA in the mapping thread waits at most this long (s) per solver step while a frame
# is tracked: its Python code would otherwise take the GIL from tracking between numba calls
BA_PAUSE_MAX_S = 0.05


class ThreadedMapping(QueuedMapping):
    """A mapping thread per map, working off the backlog."""

    def __init__(self, queue_size: int):
        super().__init__(queue_size)
        self.error: Exception | None = None
        self._thread: threading.Thread | None = None
        self._idle = threading.Event()  # clear while a frame is being tracked
        self._idle.set()

    def attach(self, mapper: Mapper) -> None:
        super().attach(mapper)
        mapper.ba_pause = lambda: self._idle.wait(BA_PAUSE_MAX_S)
        self._thread = threading.Thread(target=self._loop, name="sdvl-mapping", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Let the thread finish the frames waiting, and end it."""
        if self._thread is not None:
            self.backlog.put(None)
            self._thread.join()
        self._thread = None

    def before_frame(self) -> None:
        """Raise the mapping thread's error, if it failed; wait for room in the backlog; hold
        a BA until the frame is tracked."""
        if self.error is not None:
            raise RuntimeError("the mapping thread failed") from self.error
        self.backlog.wait_for_room()
        self._idle.clear()

    def frame_tracked(self) -> None:
        self._idle.set()

    def wait_for_room(self, timeout: float | None = None) -> bool:
        return self.backlog.wait_for_room(timeout)

    def _loop(self) -> None:
        backlog = self.backlog
        while True:
            item = backlog.take()
            if item is None:
                return
            try:
                if self.error is None:  # else drain: tracking must not wait
                    self.mapper.step(*item)
            except Exception as exc:  # re-raised in the tracking thread by before_frame
                self.error = exc
            finally:
                backlog.done()
