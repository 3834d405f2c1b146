"""A captured frame, the checks a frame must pass before tracking, and the newest-only handoff
from the capture thread to tracking."""

from __future__ import annotations

import enum
import logging
import math
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sdvl.errors import InputError

log = logging.getLogger("sdvl.camera")
# frames of one size the calibration does not fit, over this long, before any usable one: the
# configuration's fault (a camera may send a few frames of its default size when it starts)
SIZE_VERDICT_FRAMES = 30
SIZE_VERDICT_S = 2.0


class BadFrame(enum.StrEnum):
    """Why a frame was skipped."""

    MISSING = "missing"  # a recorded frame's file is not there (folder renamed, deleted)
    UNREADABLE = "unreadable"  # corrupt or truncated: cannot be decoded
    EMPTY = "empty"  # no pixels, or not an image
    WRONG_SIZE = "wrong size"  # differs from the frames being tracked
    BAD_STAMP = "bad timestamp"  # not finite, or not after the previous frame's


class BadDepth(enum.StrEnum):
    """Why a frame's depth map was not used (the image is still tracked, monocularly)."""

    UNREADABLE = "depth unreadable"  # missing or corrupt depth file, a driver error
    WRONG_SIZE = "depth of the wrong size"  # not the image's size: not registered to it
    WRONG_TYPE = "depth not in metres"  # not a float map (a raw 16-bit image not scaled)
    ALL_HOLES = "depth all holes"  # no measurement anywhere (covered, too near, too far)


@dataclass(frozen=True)
class UnreadableDepth:
    """What a source gives for a frame whose depth map it could not read."""

    detail: str


class FrameError(Exception):
    """A source could not produce one frame but the stream goes on (unlike OSError)."""

    def __init__(self, kind: BadFrame, detail: str):
        super().__init__(f"{kind}: {detail}")
        self.kind, self.detail = kind, detail


@dataclass(frozen=True)
class Frame:
    """One grey image with its own timestamp and its capture time on CLOCK_MONOTONIC, and the
    depth map registered to it (float32 metres along the optical axis, 0 = none) when the
    camera has depth."""

    index: int
    t_source: float
    t_capture: float
    image: np.ndarray
    depth: np.ndarray | None = None


class FrameCheck:
    """Counts and skips frames the tracker cannot take; logs once per kind of fault.

    The first usable frame fixes the size (the tracker is built for it); `size_ok(w, h)` raises
    InputError for a size the calibration does not fit. Frames of such a size are skipped, but
    when SIZE_VERDICT_FRAMES frames over SIZE_VERDICT_S seconds have one such size before any
    usable frame, it is the configuration's fault and the InputError is raised (exit code 2,
    before the service reports ready)."""

    def __init__(self, size_ok: Callable[[int, int], None] | None = None,
                 on_first_bad: Callable[[BadFrame], None] = lambda kind: None):
        self.size_ok = size_ok
        self.on_first_bad = on_first_bad
        self.size: tuple[int, int] | None = None
        self.counts: Counter[BadFrame] = Counter()
        self.depth_counts: Counter[BadDepth] = Counter()
        self._last_t = -math.inf
        self._unfit: dict[tuple[int, int], list[float]] = {}  # size -> [first t, count]

    def bad(self, kind: BadFrame, detail: str) -> None:
        """Count a skipped frame; the first of each kind is logged with its detail."""
        self.counts[kind] += 1
        if self.counts[kind] == 1:
            log.warning("camera: skipping a frame: %s: %s (each kind logged once, all counted)",
                        kind, detail)
            self.on_first_bad(kind)

    def check(self, t_source: float, image: object) -> bool:
        """True when the frame can be tracked; otherwise it is counted as bad."""
        if not isinstance(image, np.ndarray) or image.ndim != 2 or image.size == 0 \
                or image.dtype != np.uint8:
            self.bad(BadFrame.EMPTY, f"got {getattr(image, 'shape', type(image).__name__)}")
            return False
        height, width = image.shape
        if self.size is None and not self._fits(width, height, t_source):
            return False
        if self.size is not None and (width, height) != self.size:
            self.bad(BadFrame.WRONG_SIZE, f"{width}x{height}, tracking {self.size[0]}x"
                                          f"{self.size[1]}")
            return False
        if not math.isfinite(t_source) or t_source <= self._last_t:
            self.bad(BadFrame.BAD_STAMP, f"t = {t_source!r} after {self._last_t!r}")
            return False
        self.size, self._last_t = (width, height), t_source
        return True

    def depth(self, depth: object, image: np.ndarray) -> np.ndarray | None:
        """The frame's depth map when the tracker can use it with `image`; otherwise None (the
        image is tracked monocularly), counted, the first of each kind logged."""
        if depth is None:
            return None
        kind, detail = self._depth_fault(depth, image.shape)
        if kind is None:
            return depth
        self.depth_counts[kind] += 1
        if self.depth_counts[kind] == 1:
            log.warning("camera: frame tracked without its depth: %s: %s (each kind logged "
                        "once, all counted)", kind, detail)
        return None

    @staticmethod
    def _depth_fault(depth: object, shape: tuple[int, ...]) -> tuple[BadDepth | None, str]:
        """What is wrong with a depth map for an image of `shape` (None: nothing)."""
        if isinstance(depth, UnreadableDepth):
            return BadDepth.UNREADABLE, depth.detail
        if not isinstance(depth, np.ndarray) or depth.ndim != 2 or depth.shape != shape:
            return BadDepth.WRONG_SIZE, (f"got {getattr(depth, 'shape', type(depth).__name__)}, "
                                         f"the image is {shape}: register depth to the colour "
                                         "camera (camera.yaml depth.registered)")
        if not np.issubdtype(depth.dtype, np.floating):
            return BadDepth.WRONG_TYPE, (f"got {depth.dtype}: depth maps are float metres "
                                         "(camera.yaml depth.scale converts raw units)")
        if not np.any(depth > 0):  # NaN compares false: holes too
            return BadDepth.ALL_HOLES, ("no pixel has a measurement (all nearer than the "
                                        "camera's minimum range, e.g. on the ground, covered, "
                                        "or nothing in range)")
        return None, ""

    def _fits(self, width: int, height: int, t_source: float) -> bool:
        """Whether the first frame's size suits the calibration (see the class doc)."""
        if self.size_ok is None:
            return True
        try:
            self.size_ok(width, height)
            return True
        except InputError as exc:
            seen = self._unfit.setdefault((width, height), [t_source, 0])
            seen[1] += 1
            if seen[1] >= SIZE_VERDICT_FRAMES and t_source - seen[0] >= SIZE_VERDICT_S:
                raise
            self.bad(BadFrame.WRONG_SIZE, str(exc))
            return False


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
