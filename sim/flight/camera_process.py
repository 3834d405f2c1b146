"""The camera of a real-time closed-loop flight, as hardware of its own.

On a drone the camera exposes and reads out its frames on its own silicon and the autopilot runs
on its own board: neither costs the companion computer anything but the frame's copy. Here both
are simulated on the companion's machine, so the camera is a process of its own (rendering a
320x240 frame of the world takes ~15 ms of CPU, half a core at 30 fps) and, like the autopilot's
process, it runs at a raised priority (`HARDWARE_NICE`): the service and the busy processes of a
loaded-machine check share what is left, as they would share a companion computer's cores.

At each frame time the camera process reads the vehicle's true pose (the autopilot process's
TruthShare) at that instant (exposure), renders the frame there and writes it into a ring of
shared-memory slots; a few bytes on a pipe tell the service's side (`SharedCamera`, a live
FrameSource) which slot to copy. A reader that falls a whole ring behind finds its slot
overwritten and skips that frame (counted in `overwritten`), as a camera's driver drops frames
nobody fetched.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import struct
from multiprocessing import shared_memory

import numpy as np

from daemon.camera import Pacer
from sim.flight.world import FlightWorld
from sim.replay.autopilot_process import START_METHOD

log = logging.getLogger("sdvl.fly")
SLOTS = 8  # 0.27 s of frames at 30 fps: a service that far behind has dropped them anyway
HARDWARE_NICE = -15  # the simulated camera and autopilot before the service and any load
WAIT_S = 0.1  # how often a waiting read looks whether the camera has stopped
SILENT_S = 2.0  # no frame for this long: the camera is gone (OSError: the service reopens)
_INDEX = struct.Struct("<q")


def raise_priority(what: str) -> bool:
    """Give this process the simulated hardware's priority; False (and a log line saying the
    check is harsher than a drone) when the system refuses (not root)."""
    try:
        os.nice(HARDWARE_NICE)
        return True
    except OSError as exc:
        log.warning("%s keeps normal priority (%s): the service shares the CPU with the "
                    "simulation too, harsher than on a drone", what, exc)
        return False


class TruthShare:
    """The vehicle's true pose (T_ned_body) and its time (s since boot), shared between
    processes."""

    def __init__(self, array: object | None = None) -> None:
        self.array = (multiprocessing.get_context(START_METHOD).Array("d", 17) if array is None
                      else array)

    def write(self, t: float, T: np.ndarray) -> None:
        with self.array.get_lock():
            self.array[0] = t
            self.array[1:] = T.ravel()

    def read(self) -> tuple[float, np.ndarray]:
        with self.array.get_lock():
            values = np.array(self.array[:])
        return float(values[0]), values[1:].reshape(4, 4)


class FrameRing:
    """SLOTS frames of one size in shared memory (uint8 images, and float32 depth maps with
    `depth`), each with its header (frame index, t_source, t_capture); made by the service's
    side, attached by the camera process by name."""

    def __init__(self, shape: tuple[int, int], depth: bool = False, name: str | None = None,
                 header: object | None = None):
        pixels = SLOTS * shape[0] * shape[1]
        size = pixels * (5 if depth else 1)
        self.memory = (shared_memory.SharedMemory(create=True, size=size) if name is None
                       else shared_memory.SharedMemory(name=name))
        self.owner = name is None
        self.images = np.ndarray((SLOTS, *shape), np.uint8, buffer=self.memory.buf)
        self.depths = (np.ndarray((SLOTS, *shape), np.float32, buffer=self.memory.buf,
                                  offset=pixels) if depth else None)
        self.header = (header if header is not None
                       else multiprocessing.get_context(START_METHOD).Array("d", 3 * SLOTS))

    def write(self, index: int, t_source: float, t_capture: float, image: np.ndarray,
              depth: np.ndarray | None = None) -> None:
        slot = index % SLOTS
        with self.header.get_lock():
            self.header[3 * slot] = -1.0  # being written
        self.images[slot] = image
        if self.depths is not None:
            self.depths[slot] = 0.0 if depth is None else depth
        with self.header.get_lock():
            self.header[3 * slot:3 * slot + 3] = [float(index), t_source, t_capture]

    def read(self, index: int) -> tuple | None:
        """(t_source, t_capture, image[, depth map]) of frame `index`, copied; None when its
        slot has been written again since (the reader fell a ring behind)."""
        slot = index % SLOTS
        with self.header.get_lock():
            stamp = list(self.header[3 * slot:3 * slot + 3])
        frame = (stamp[1], stamp[2], self.images[slot].copy())
        if self.depths is not None:
            frame += (self.depths[slot].copy(),)
        with self.header.get_lock():
            still = self.header[3 * slot] == stamp[0]
        return frame if stamp[0] == float(index) and still else None

    def close(self) -> None:
        del self.images, self.depths
        self.memory.close()
        if self.owner:
            with contextlib.suppress(FileNotFoundError):
                self.memory.unlink()


def camera_process(conn: multiprocessing.connection.Connection, preset: str, seed: int,
                   size: tuple[int, int] | None, depth: bool, truth_array: object,
                   ring_name: str, header: object, fps: float) -> None:
    """The child: render one frame to compile and warm the renderer, say ready, then expose,
    render and hand over a frame every 1/fps s of the autopilot's clock until told to stop."""
    raise_priority("the simulated camera")
    world = FlightWorld.of_preset(preset, seed, size)
    truth = TruthShare(truth_array)
    ring = FrameRing(world.camera.size[::-1], depth, ring_name, header)
    world.frame(0, 0.0, np.eye(4), depth)
    conn.send("ready")
    boot = conn.recv()  # the autopilot's boot instant on CLOCK_MONOTONIC
    pacer, index = Pacer(), 0
    try:
        while not conn.poll():
            index += 1
            t_capture = pacer.wait(index / fps)
            _, T_ned_body = truth.read()
            t = t_capture - boot
            ring.write(index, t, t_capture, *world.frame(index, t, T_ned_body, depth))
            conn.send_bytes(_INDEX.pack(index))
    except (BrokenPipeError, EOFError):
        pass  # the service's side has gone: the flight is over
    finally:
        ring.close()


class SharedCamera:
    """The service's live FrameSource for the camera process: each read waits for the next
    frame's index and copies it out of the ring."""

    live, finite, blocks = True, False, False
    name = "rendered world (camera process)"

    def __init__(self, conn: multiprocessing.connection.Connection, ring: FrameRing,
                 camera: object):
        self.conn, self.ring, self.camera = conn, ring, camera
        self.offered = 0  # frames the camera exposed, read or not
        self.overwritten = 0  # frames the reader came too late for

    def open(self) -> None:
        """Nothing to open: the camera process runs from the flight's start."""

    def read(self) -> tuple:
        """The next frame the ring still holds (with its depth map from a depth camera);
        OSError when the camera process is gone or silent for SILENT_S."""
        waited = 0.0
        while True:
            if not self.conn.poll(WAIT_S):
                waited += WAIT_S
                if waited >= SILENT_S:
                    raise OSError(f"the camera process sent nothing for {SILENT_S:g} s")
                continue
            try:
                index = _INDEX.unpack(self.conn.recv_bytes())[0]
            except (EOFError, OSError) as exc:
                raise OSError("the camera process has ended") from exc
            self.offered = index
            frame = self.ring.read(index)
            if frame is not None:
                return frame
            self.overwritten += 1

    def close(self) -> None:
        """Nothing to release per open: the ring lives as long as the flight."""
