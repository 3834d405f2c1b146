"""The service's frame recorder (camera.record): every frame the capture thread accepts, with
its depth map when the camera gives one, written in the layout daemon/recordings.py plays back
as camera.source: frames.txt + images/*.png, depth.txt + depth/*.png (16-bit, 1 mm) and
camera.yaml with the intrinsics and the depth unit. A flight recorded with a depth camera so
replays with depth.

A thread of its own encodes and writes: the capture thread only offers a frame; when the
writer is behind (a slow card) the frame is not recorded and counted, and a write that fails
(a full disk) ends the recording with one log line, never the service."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

import cv2

from calib.camera import CameraModel
from calib.camera_yaml import save_camera
from calib.depth_camera import DepthSpec
from daemon.frames import Frame

log = logging.getLogger("sdvl.recorder")
RECORD_QUEUE = 30  # frames: a second of a 30 fps camera's writer stall before frames are lost
DEPTH_SPEC = DepthSpec(scale=0.001)  # 1 mm units: 65 m of range in 16 bits, as `sdvl render`
HEADER = "# timestamp filename\n"


def new_folder(parent: Path) -> Path:
    """A fresh folder under `parent` named after the UTC start time (never an old one)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    for n in range(1, 1000):
        folder = parent / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            folder.mkdir(parents=True)
            return folder
        except FileExistsError:
            continue
    raise OSError(f"{parent}: no free folder name for {stamp}")


class FrameRecorder(threading.Thread):
    """Writes offered frames into `parent`/<UTC start time>/; `camera_at(width, height)` gives
    the intrinsics for the first frame's size (camera.yaml); with `depth`, the frames' depth
    maps too. `written`, `dropped` (writer behind) and `error` (why it stopped) for the log."""

    def __init__(self, parent: Path, camera_at: Callable[[int, int], CameraModel],
                 depth: bool):
        super().__init__(name="recorder", daemon=True)
        self.parent, self.camera_at, self.depth = Path(parent), camera_at, depth
        self.folder: Path | None = None
        self.written = self.dropped = 0
        self.error: str | None = None
        self._queue: queue.Queue[Frame] = queue.Queue(RECORD_QUEUE)
        self._stopping = threading.Event()
        self._lists: list[TextIO] = []

    def offer(self, frame: Frame) -> None:
        """Queue a frame for writing; never waits (a full queue drops it, counted)."""
        if self.error is not None or self._stopping.is_set():
            return
        try:
            self._queue.put_nowait(frame)
        except queue.Full:
            self.dropped += 1

    def stop(self, timeout: float) -> None:
        """Write what is queued (up to `timeout` seconds), then close the lists."""
        self._stopping.set()
        self.join(timeout)
        log.info("recorder: %d frames written to %s (%d not recorded: writer behind)%s",
                 self.written, self.folder, self.dropped,
                 f"; stopped early: {self.error}" if self.error else "")

    def run(self) -> None:
        try:
            while not (self._stopping.is_set() and self._queue.empty()):
                try:
                    frame = self._queue.get(timeout=0.1)
                except queue.Empty:
                    continue
                self._write(frame)
        except OSError as exc:  # a full or read-only disk: the recording ends, not the service
            self.error = str(exc)
            log.error("recorder: %s; recording stopped (the service goes on)", exc)
        finally:
            for handle in self._lists:
                handle.close()

    def _start(self, frame: Frame) -> None:
        """The folder, camera.yaml and the two lists, on the first frame (its size)."""
        self.folder = new_folder(self.parent)
        (self.folder / "images").mkdir()
        height, width = frame.image.shape
        save_camera(self.camera_at(width, height), self.folder / "camera.yaml",
                    comment="sdvl run: camera.record", depth=DEPTH_SPEC if self.depth else None)
        names = ["frames.txt"]
        if self.depth:
            (self.folder / "depth").mkdir()
            names.append("depth.txt")
        for name in names:  # line-buffered: a recording cut by a power loss still plays
            handle = open(self.folder / name, "w", buffering=1)  # noqa: SIM115 (closed in run)
            handle.write(HEADER)
            self._lists.append(handle)

    def _write(self, frame: Frame) -> None:
        """One frame's image (and depth map) and its list lines; OSError when a write fails."""
        if self.folder is None:
            self._start(frame)
        name = f"{self.written:06d}.png"
        _imwrite(self.folder / "images" / name, frame.image)
        self._lists[0].write(f"{frame.t_source:.6f} images/{name}\n")
        if self.depth and frame.depth is not None:  # none or unusable: no line, none on replay
            _imwrite(self.folder / "depth" / name, DEPTH_SPEC.to_raw(frame.depth))
            self._lists[1].write(f"{frame.t_source:.6f} depth/{name}\n")
        self.written += 1


def _imwrite(path: Path, image) -> None:
    """cv2.imwrite that raises OSError instead of returning False (a full disk)."""
    if not cv2.imwrite(str(path), image):
        raise OSError(f"{path}: cannot write (disk full or read-only?)")
