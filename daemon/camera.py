"""Frame sources and the capture thread.

A source yields (t_source, t_capture, grey image); t_capture is CLOCK_MONOTONIC seconds taken at
capture. Live sources (devices, GStreamer, the test pattern, real-time playback) let the newest
frame replace an untaken one; as-fast-as-possible playback waits for the tracker instead.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from calib.camera import CameraModel
from daemon.frames import (
    BadFrame,
    Frame,
    FrameCheck,
    FrameError,
    LatestSlot,
    UnreadableDepth,
)
from daemon.health import Health
from daemon.recordings import Recording
from sdvl.errors import InputError

log = logging.getLogger("sdvl.camera")
DEVICE_STAMP_MAX_AGE_S = 0.5  # trust a driver's buffer stamp only if it is this recent
HAS_GSTREAMER = re.search(r"GStreamer:\s*YES", cv2.getBuildInformation()) is not None


class FrameSource(Protocol):
    """What the capture thread reads from."""

    name: str
    camera: CameraModel | None  # intrinsics when the source knows them (datasets, test pattern)
    live: bool  # True: drop the oldest frame when tracking is behind; False: wait for it
    finite: bool  # True: the end of the stream ends the service; False: reopen and go on
    # True: a device whose open or read can hang (watched by camera.stall_timeout_s); sources
    # without the attribute are files or generators, which are slow at worst (a renderer)
    blocks: bool

    def open(self) -> None:
        """Open the device or file; OSError when it is not there (the caller retries)."""

    def read(self) -> tuple[float, float, np.ndarray] | None:
        """The next (t_source, t_capture, grey image); None at the end; OSError if it broke.
        A source with depth adds the frame's depth map (float32 metres registered to the
        image, None or frames.UnreadableDepth when it has none) as a fourth element."""

    def close(self) -> None:
        """Release the device."""


def grey(image: np.ndarray) -> np.ndarray:
    """A uint8 single-channel view of what a capture or a video file returned."""
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype == np.uint16:  # 16-bit sensors: keep the top 8 bits, same for every frame
        return (image >> 8).astype(np.uint8)
    return image if image.dtype == np.uint8 else cv2.convertScaleAbs(image)


class Pacer:
    """Releases frames at their own timestamps, starting now (real-time playback)."""

    def __init__(self) -> None:
        self._offset: float | None = None

    def wait(self, t_source: float) -> float:
        """Sleep until frame time `t_source` is due; returns the monotonic release time."""
        now = time.monotonic()
        if self._offset is None:
            self._offset = now - t_source
        delay = t_source + self._offset - now
        if delay > 0:
            time.sleep(delay)
        return time.monotonic()


class OpenCVSource:
    """A V4L2 device (index or /dev path), a GStreamer pipeline or a video file via OpenCV."""

    camera = None

    def __init__(self, spec: str, width: int = 0, height: int = 0, fps: float = 0.0,
                 realtime: bool = True):
        self.name = spec
        self.spec, self.size, self.fps = spec, (width, height), fps
        self.is_file = Path(spec).is_file() and not spec.startswith("/dev/")
        self.finite = self.is_file
        self.blocks = not self.is_file
        self.live = realtime or not self.is_file
        self._pacer = Pacer() if self.is_file and realtime else None
        self._cap: cv2.VideoCapture | None = None

    def open(self) -> None:
        if self.spec.isdigit():
            cap = cv2.VideoCapture(int(self.spec), cv2.CAP_V4L2)
        elif "!" in self.spec:
            if not HAS_GSTREAMER:
                raise OSError("this OpenCV has no GStreamer (pip wheels do not): install the "
                              "system's python3-opencv or use a V4L2 device")
            cap = cv2.VideoCapture(self.spec, cv2.CAP_GSTREAMER)
        else:
            if not self.is_file and not Path(self.spec).exists():
                raise OSError(f"no such device {self.spec}")
            cap = cv2.VideoCapture(self.spec)
        if not cap.isOpened():
            cap.release()
            raise OSError(f"OpenCV cannot open {self.spec}")
        if not self.is_file:
            if self.size[0] and self.size[1]:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[0])
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[1])
            if self.fps:
                cap.set(cv2.CAP_PROP_FPS, self.fps)
        self._cap = cap

    def read(self) -> tuple[float, float, np.ndarray] | None:
        ok = self._cap.grab()
        t_capture = time.monotonic()
        if not ok:
            if self.is_file:
                return None
            raise OSError(f"{self.spec}: frame grab failed (device unplugged?)")
        ok, image = self._cap.retrieve()
        if not ok or image is None:
            raise OSError(f"{self.spec}: frame decode failed")
        stamp = self._cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        if self.is_file:
            t_capture = self._pacer.wait(stamp) if self._pacer else t_capture
            return stamp, t_capture, grey(image)
        if 0.0 <= t_capture - stamp < DEVICE_STAMP_MAX_AGE_S:  # V4L2 buffer stamp (monotonic)
            t_capture = stamp
        return t_capture, t_capture, grey(image)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class SequenceSource:
    """Anything with `.frames()` yielding (t, grey image) and a `.camera` (e.g. a
    sim.sequence.Sequence): played at its timestamps or as fast as tracking takes frames.
    With `depth`, each frame comes with the sequence's `depth(i)` map (a depth camera)."""

    finite, blocks = True, False

    def __init__(self, sequence: object, realtime: bool = True, name: str | None = None,
                 depth: bool = False):
        if depth:
            need_depth(sequence)
        self.sequence = sequence
        self.name = name or getattr(sequence, "name", "sequence")
        self.camera = getattr(sequence, "camera", None)
        self.live = realtime
        self.depth = depth
        self._pacer = Pacer() if realtime else None
        self._frames: Iterator | None = None

    def open(self) -> None:
        if self._frames is None:
            self._frames = enumerate(self.sequence.frames())

    def read(self) -> tuple | None:
        item = next(self._frames, None)
        if item is None:
            return None
        index, (t, image) = item
        depth = sequence_depth(self.sequence, index) if self.depth else None
        t_capture = self._pacer.wait(float(t)) if self._pacer else time.monotonic()
        frame = (float(t), t_capture, grey(np.asarray(image)))
        return frame if not self.depth else (*frame, depth)

    def close(self) -> None:
        """Nothing to release; the iterator continues if the capture thread reopens."""


def need_depth(sequence: object) -> None:
    """InputError when camera.depth is on and the sequence has no depth maps."""
    if not getattr(sequence, "has_depth", False):
        raise InputError(f"camera.depth is on but '{getattr(sequence, 'name', sequence)}' "
                         "has no depth maps (a depth.txt beside its frame list, or a "
                         "synthetic preset): add them or set camera.depth = false")


def sequence_depth(sequence: object, index: int) -> np.ndarray | UnreadableDepth | None:
    """Frame `index`'s depth map of a sequence with depth (None: it has none);
    UnreadableDepth when its file is missing or corrupt."""
    try:
        return sequence.depth(index)
    except (InputError, OSError) as exc:
        return UnreadableDepth(str(exc))


class RecordingSource(SequenceSource):
    """Recorded frames on disk (daemon/recordings.py) played as a camera. Each image is read
    when it is due; one that is missing or cannot be decoded is a FrameError, so the stream
    goes on with the next (a folder renamed during a run gives missing frames until it is
    back). With `depth`, its depth map (depth.txt) is read with it, as SequenceSource's."""

    sequence: Recording

    def open(self) -> None:
        if self._frames is None:
            self._frames = enumerate(zip(self.sequence.timestamps, self.sequence.files,
                                         strict=True))

    def read(self) -> tuple | None:
        item = next(self._frames, None)
        if item is None:
            return None
        index, (t, path) = item
        t = float(t)
        t_capture = self._pacer.wait(t) if self._pacer else time.monotonic()
        try:
            data = np.fromfile(path, np.uint8)
        except OSError as exc:
            raise FrameError(BadFrame.MISSING, f"{path}: {exc.strerror}") from None
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
        if image is None:
            raise FrameError(BadFrame.UNREADABLE, str(path))
        if not self.depth:
            return t, t_capture, image
        return t, t_capture, image, sequence_depth(self.sequence, index)


class TestPatternSource:
    """A textured scene seen by a camera drifting on a small circle: frames at `fps` with no
    hardware, for bring-up, benchmarks and tests."""

    __test__ = False  # not a pytest class
    live, finite, blocks = True, False, False

    def __init__(self, width: int = 320, height: int = 240, fps: float = 30.0, seed: int = 7):
        rng = np.random.default_rng(seed)
        noise = rng.random((height // 4 + 16, width // 4 + 16)).astype(np.float32)
        big = cv2.resize(noise, None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)
        self.texture = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        self.name, self.size, self.period = "testpattern", (width, height), 1.0 / fps
        f = 0.8 * width
        self.camera = CameraModel(width, height, f, f, width / 2, height / 2, "none", [])
        self._next = 0.0
        self._index = 0

    def open(self) -> None:
        self._next = time.monotonic()

    def read(self) -> tuple[float, float, np.ndarray]:
        delay = self._next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        t_capture = time.monotonic()
        self._next = max(self._next + self.period, t_capture - self.period)
        phase = 2 * np.pi * self._index / 300.0
        self._index += 1
        x = round(28 + 24 * np.cos(phase))
        y = round(28 + 24 * np.sin(phase))
        w, h = self.size
        return t_capture, t_capture, self.texture[y:y + h, x:x + w].copy()

    def close(self) -> None:
        """Nothing to release."""


class CaptureThread(threading.Thread):
    """Reads a source into the slot; reopens it with back-off when it fails or disappears.

    Input never stops it: a frame the source cannot produce (FrameError) or one the tracker
    cannot take (FrameCheck) is counted and skipped. What the service watches: `busy` (the
    source call in progress and since when, to see a device that never answers), the time of
    the last good frame and of the last read, and `error` when the thread stopped on a size
    the calibration does not fit (InputError) or on a bug."""

    def __init__(self, source: FrameSource, slot: LatestSlot, backoff: tuple[float, float],
                 on_state: Callable[[Health], None] = lambda state: None,
                 check: FrameCheck | None = None,
                 record: Callable[[Frame], None] | None = None):
        super().__init__(name="capture", daemon=True)
        self.source, self.slot, self.backoff = source, slot, backoff
        self.record = record  # gets every accepted frame, also those tracking then drops
        self.on_state = on_state
        self.check = check or FrameCheck()
        self.stopping = threading.Event()
        self.frames = 0
        self.error: BaseException | None = None
        self.busy: tuple[str, float] | None = None  # ("open" or "read", monotonic start)
        self.watch_stalls = getattr(source, "blocks", False)
        self.last_frame_t: float | None = None  # monotonic time of the last good frame
        self.last_read_t: float | None = None  # ... of the last read that gave a frame, bad or not

    def run(self) -> None:
        try:
            self._run()
        except InputError as exc:  # the calibration does not fit the frames: config
            self.error = exc
        except Exception as exc:  # a bug: the service sees the thread end and restarts
            log.exception("capture thread failed")
            self.error = exc
        finally:
            self.busy = None
            self.slot.close()

    def _run(self) -> None:
        delay = self.backoff[0]
        while not self.stopping.is_set():
            try:
                self._call("open", self.source.open)
            except Exception as exc:  # OSError: not there; anything else: the driver's fault
                log.warning("camera %s: %s; retrying in %.1f s", self.source.name, exc, delay)
                self.on_state(Health.NO_CAMERA)
                self.stopping.wait(delay)
                delay = min(2 * delay, self.backoff[1])
                continue
            delay = self.backoff[0]
            log.info("camera %s: open", self.source.name)
            ended = self._pump()
            self.source.close()
            if ended:
                break

    def _call(self, what: str, fn: Callable[[], object]) -> object:
        """fn() with `busy` saying what is in progress since when (for a device that can
        hang; a slow renderer or file is not a blocked camera)."""
        self.busy = (what, time.monotonic()) if self.watch_stalls else None
        try:
            return fn()
        finally:
            self.busy = None

    def _pump(self) -> bool:
        """Move frames into the slot until stop, failure (False) or a finite end (True)."""
        while not self.stopping.is_set():
            try:
                item = self._call("read", self.source.read)
            except OSError as exc:
                log.warning("camera %s: %s; reopening", self.source.name, exc)
                self.on_state(Health.NO_CAMERA)
                return False
            except FrameError as exc:
                self._bad(exc.kind, exc.detail)
                continue
            except Exception as exc:  # a decoder or driver error on one frame
                self._bad(BadFrame.UNREADABLE, f"{type(exc).__name__}: {exc}")
                continue
            if item is None:
                if self.source.finite:
                    log.info("camera %s: end of stream after %d frames", self.source.name,
                             self.frames)
                    return True
                return False
            t_source, t_capture, image, *depth = item  # a depth camera's map comes fourth
            self.last_read_t = time.monotonic()
            if not self.check.check(t_source, image):
                continue
            depth = self.check.depth(depth[0], image) if depth else None
            frame = Frame(self.frames, t_source, t_capture, image, depth)
            if self.record is not None:
                self.record(frame)
            if not self.slot.put(frame, wait=not self.source.live):
                return True
            self.last_frame_t = time.monotonic()
            self.frames += 1
        return True

    def _bad(self, kind: BadFrame, detail: str) -> None:
        """A read that returned no usable frame (the source is there: not a lost camera)."""
        self.last_read_t = time.monotonic()
        self.check.bad(kind, detail)

    def stop(self) -> None:
        """Ask the thread to finish; the slot is closed so a waiting put returns."""
        self.stopping.set()
        self.slot.close()
