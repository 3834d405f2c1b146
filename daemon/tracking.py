"""The tracking thread: newest frame -> tracker -> estimator -> handed to the asyncio loop."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from daemon.estimate import Estimator, VisionEstimate
from daemon.frames import Frame, LatestSlot

log = logging.getLogger("sdvl.tracking")


@dataclass(frozen=True)
class TrackedFrame:
    """What the loop learns about one processed frame."""

    frame_index: int
    t_source: float
    t_capture: float
    result: object  # vo.result.FrameResult
    estimate: VisionEstimate | None
    t_start: float  # monotonic time tracking of this frame started
    track_s: float  # tracker.process wall time
    t_done: float  # monotonic time the estimate was ready


class TrackingThread(threading.Thread):
    """Runs the tracker on the newest frames; the tracker is built on the first frame (its
    size fixes the camera model) by `make_tracker(frame)`."""

    def __init__(self, slot: LatestSlot, make_tracker: Callable[[Frame], object],
                 estimator: Estimator, deliver: Callable[[TrackedFrame], None],
                 on_end: Callable[[], None]):
        super().__init__(name="tracking", daemon=True)
        self.slot, self.make_tracker, self.estimator = slot, make_tracker, estimator
        self.deliver, self.on_end = deliver, on_end
        self.stopping = threading.Event()
        self.tracker = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # reported to the service, which stops with an error
            log.exception("tracking failed")
            self.error = exc
        finally:
            if self.tracker is not None:
                self.tracker.close()
            self.on_end()

    def _loop(self) -> None:
        while not self.stopping.is_set():
            frame = self.slot.get(timeout=0.1)
            if frame is None:
                if self.slot.closed:
                    return
                continue
            if self.tracker is None:
                self.tracker = self.make_tracker(frame)
            t_start = time.monotonic()
            start = time.perf_counter()
            result = self.tracker.process(frame.image, frame.t_source)
            track_s = time.perf_counter() - start
            estimate = self.estimator.on_frame(result, frame.t_capture)
            self.deliver(TrackedFrame(frame.index, frame.t_source, frame.t_capture, result,
                                      estimate, t_start, track_s, time.monotonic()))

    def stop(self) -> None:
        """Finish after the frame in hand."""
        self.stopping.set()
