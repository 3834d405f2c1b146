"""A captured frame and the newest-only handoff from the capture thread to tracking."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One grey image with its own timestamp and its capture time on CLOCK_MONOTONIC."""

    index: int
    t_source: float
    t_capture: float
    image: np.ndarray


class LatestSlot:
    """Holds at most one frame. A live camera overwrites an untaken frame (counted as dropped:
    the oldest goes, never the newest); a replay waits until tracking took the previous one."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._closed = False
        self.dropped = 0
        self.delivered = 0

    def put(self, frame: Frame, wait: bool = False) -> bool:
        """Offer a frame; with `wait`, block until the slot is free. False once closed."""
        with self._cond:
            if wait:
                self._cond.wait_for(lambda: self._frame is None or self._closed)
            if self._closed:
                return False
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self._cond.notify_all()
            return True

    def get(self, timeout: float) -> Frame | None:
        """The newest frame, waiting up to `timeout` seconds; None on timeout or when closed."""
        with self._cond:
            self._cond.wait_for(lambda: self._frame is not None or self._closed, timeout)
            frame, self._frame = self._frame, None
            if frame is not None:
                self.delivered += 1
            self._cond.notify_all()
            return frame

    def close(self) -> None:
        """Wake every waiter; later puts are refused, a frame still held can be taken."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed
