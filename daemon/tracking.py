"""The tracking thread: newest frame -> tracker -> estimator -> handed to the asyncio loop."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from daemon.estimate import Estimator, VisionEstimate
from daemon.frames import Frame, LatestSlot
from daemon.obstacle_feed import ObstacleFeed
from sdvl.errors import InputError

log = logging.getLogger("sdvl.tracking")
HANDOFF_WAIT_S = 0.05  # the mapping thread waits at most this long for a frame's handoff
MAX_FAILED_FRAMES = 30  # failures in a row (a second of frames) before the thread gives up
# one frame taking longer than this is a hang: far above a starved CPU's frame time, and the
# first frame may compile every kernel (minutes on a Raspberry Pi without the numba cache)
TRACK_HUNG_S = 120.0
FIRST_FRAME_HUNG_S = 900.0


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
    obstacles: object = None  # daemon.obstacles.ObstacleScan of its depth map, when due


def track(tracker: object, frame: Frame, orientation: object = None) -> object:
    """The tracker's result for a frame, with its depth map when it has one and the camera's
    orientation (vo.rotation_prior.Orientation) when the estimator knows it."""
    extra = {"depth": frame.depth, "orientation": orientation}
    return tracker.process(frame.image, frame.t_source,
                           **{key: value for key, value in extra.items() if value is not None})


class HandoffGate:
    """Holds the tracker's mapping thread back from a frame's mapping step until the loop has
    handled that frame's estimate. Mapping is background work; started the moment tracking
    hands it the frame, it takes the GIL and a core from the estimator, the handoff to the loop
    and the send, which are what the autopilot waits for. The wait is bounded, so a slow or
    stopped loop never stalls mapping."""

    def __init__(self, timeout_s: float = HANDOFF_WAIT_S):
        self.timeout_s = timeout_s
        self._cond = threading.Condition()
        self._done_t = -math.inf

    def done(self, t_source: float) -> None:
        """The loop has handled the frame with this source time (and all before it)."""
        with self._cond:
            self._done_t = max(self._done_t, t_source)
            self._cond.notify_all()

    def wait(self, frame: object) -> bool:
        """Block until the frame (a vo Frame, `.t` its source time) was handled; False when
        the timeout released it instead."""
        with self._cond:
            return self._cond.wait_for(lambda: self._done_t >= frame.t, self.timeout_s)


class TrackingThread(threading.Thread):
    """Runs the tracker on the newest frames; the tracker is built on the first frame (its
    size fixes the camera model) by `make_tracker(frame)`.

    An exception from the tracker on one frame is logged with its traceback once per kind and
    counted; the tracker is then rebuilt (a new map: reset_counter changes). One from the
    estimator loses that frame's estimate. Only MAX_FAILED_FRAMES failures in a row end the
    thread (the service then exits for systemd to restart it); building the tracker is
    allowed to fail with InputError (the calibration), which ends the service with code 2."""

    def __init__(self, slot: LatestSlot, make_tracker: Callable[[Frame], object],
                 estimator: Estimator, deliver: Callable[[TrackedFrame], None],
                 on_end: Callable[[], None], obstacles: ObstacleFeed | None = None):
        super().__init__(name="tracking", daemon=True)
        self.slot, self.make_tracker, self.estimator = slot, make_tracker, estimator
        self.deliver, self.on_end, self.obstacles = deliver, on_end, obstacles
        self.stopping = threading.Event()
        self.gate = HandoffGate()
        self.tracker = None
        self.error: BaseException | None = None
        self.failures: Counter[str] = Counter()  # "tracker: ValueError" -> count
        self.frames = 0
        self._failed_in_row = 0
        self._busy_since: float | None = None  # monotonic start of the frame in the tracker

    def run(self) -> None:
        try:
            self._loop()
        except InputError as exc:  # reported by the service, which stops with code 2
            self.error = exc
        except Exception as exc:  # reported to the service, which stops with an error
            log.exception("tracking failed")
            self.error = exc
        finally:
            self.gate.done(math.inf)  # no more handoffs: mapping finishes its queue unheld
            self.close_tracker()
            self.on_end()

    def _loop(self) -> None:
        while not self.stopping.is_set():
            if not self._mapping_has_room():
                continue
            frame = self.slot.get(timeout=0.1)
            if frame is None:
                if self.slot.closed:
                    return
                continue
            tracked = self.step(frame)
            if tracked is not None:
                self.deliver(tracked)

    def step(self, frame: Frame) -> TrackedFrame | None:
        """Track one frame and estimate, on the caller's thread (the loop's body; a lockstep
        replay calls it directly); None when the tracker failed on it."""
        if self.tracker is None:
            self.tracker = self.make_tracker(frame)
        self._gate_mapping()
        t_start = self._busy_since = time.monotonic()
        start = time.perf_counter()
        try:
            result = track(self.tracker, frame, self.estimator.orientation(frame.t_capture))
        except Exception as exc:
            self._failed("tracker", exc)
            self.close_tracker()  # rebuilt on the next frame: a new map
            return None
        finally:
            self._busy_since = None
        track_s = time.perf_counter() - start
        self.frames += 1
        try:
            estimate = self.estimator.on_frame(result, frame.t_capture)
            self._failed_in_row = 0
        except Exception as exc:
            self._failed("estimator", exc)
            estimate = None
        t_done = time.monotonic()
        return TrackedFrame(frame.index, frame.t_source, frame.t_capture, result,
                            estimate, t_start, track_s, t_done,
                            self._obstacles(frame, estimate))

    def _obstacles(self, frame: Frame, estimate: VisionEstimate | None) -> object:
        """The frame's obstacle scan when obstacles are on and one is due (after the estimate:
        the autopilot waits for that first); a failure is counted, never the frame's."""
        if self.obstacles is None:
            return None
        try:
            return self.obstacles.scan(frame, getattr(self.tracker, "camera", None), estimate)
        except Exception as exc:
            key = f"obstacles: {type(exc).__name__}"
            self.failures[key] += 1
            if self.failures[key] == 1:
                log.error("obstacle distances failed on a frame (%s; logged once)", exc,
                          exc_info=exc)
            return None

    def _failed(self, where: str, exc: Exception) -> None:
        """Count a failure on one frame; its first occurrence is logged with the traceback."""
        key = f"{where}: {type(exc).__name__}"
        self.failures[key] += 1
        self._failed_in_row += 1
        if self.failures[key] == 1:
            log.error("%s failed on a frame, skipped (%s; each kind logged once)", where, exc,
                      exc_info=exc)
        if self._failed_in_row >= MAX_FAILED_FRAMES:
            raise RuntimeError(f"{where} failed on {self._failed_in_row} frames in a row, "
                               f"the last with {type(exc).__name__}: {exc}") from exc

    def close_tracker(self) -> None:
        """Close the tracker (a new one is built for the next frame)."""
        tracker, self.tracker = self.tracker, None
        if tracker is None:
            return
        try:
            tracker.close()
        except Exception:
            log.exception("closing the tracker failed")

    def hung_for(self, now: float) -> float | None:
        """Seconds the tracker has been on one frame, when that is longer than a frame can
        take (the first frame may compile the kernels); None otherwise."""
        since = self._busy_since
        limit = FIRST_FRAME_HUNG_S if self.frames == 0 else TRACK_HUNG_S
        return None if since is None or now - since <= limit else now - since

    def _mapping_has_room(self) -> bool:
        """Wait (at most 0.1 s) until the tracker's mapping backlog has room for a frame, so
        the frame taken next is the newest: a slow mapping thread makes the service skip whole
        frames (the slot counts them dropped) rather than track against a map that lags."""
        wait = getattr(self.tracker, "wait_for_mapping", None)
        return wait is None or wait(0.1)

    def _gate_mapping(self) -> None:
        """Put the handoff gate on the tracker's mapping thread (again after a new map, which
        comes with a new mapper); inline mapping runs in this thread and is not gated."""
        mapper = getattr(self.tracker, "mapper", None)
        if getattr(self.tracker, "threaded", False) and mapper.before_step != self.gate.wait:
            mapper.before_step = self.gate.wait

    def stop(self) -> None:
        """Finish after the frame in hand."""
        self.stopping.set()
