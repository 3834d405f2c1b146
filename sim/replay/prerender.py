"""Frames rendered before a real-time replay starts: a synthetic flight renders each frame on
the fly (tens of milliseconds a frame), which a real camera does not do on the companion's CPU,
so in real time the renderer would fall behind the flight's own clock. The frames are rendered
by worker processes on all cores first (while the caller's own work, e.g. the tracker's warm-up,
runs alongside) and read back like a recorded sequence's; they are kept for the next run of the
same flight (sim/replay/frame_cache.py)."""

from __future__ import annotations

import dataclasses
import multiprocessing
import multiprocessing.pool
import os
import shutil
import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import cv2

from sim.replay import frame_cache
from sim.sequence import Sequence, load_grey

T = TypeVar("T")
_RENDER: dict = {}  # the sequence and folder the forked workers render from


def renders_on_the_fly(sequence: object) -> bool:
    """Synthetic flights (sim.synth) name their preset in extras."""
    return "preset" in getattr(sequence, "extras", {})


_WORKER_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)


def _default_signals() -> None:
    """In a forked worker: the default handlers, then the signals unblocked, so a SIGTERM that
    arrived meanwhile ends it (the parent's handler, e.g. `sdvl run`'s that only sets a flag,
    would keep it alive and the pool's exit would wait for it forever)."""
    for sig in _WORKER_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _WORKER_SIGNALS)


def _render_pool(workers: int) -> multiprocessing.pool.Pool:
    """A pool of forked workers that start with the signals blocked until `_default_signals`."""
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _WORKER_SIGNALS)
    try:
        return multiprocessing.get_context("fork").Pool(workers, _default_signals)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _render(i: int) -> int:
    if _RENDER["stop"].is_set():  # a frame failed: the ones left end at once
        return i
    sequence, folder = _RENDER["sequence"], _RENDER["folder"]
    cv2.imwrite(str(folder / f"{i:06d}.png"), sequence.image_loader(i))
    return i


def prerendered(sequence: Sequence, folder: Path, frames: int, on_frame: Callable[[int], None],
                alongside: Callable[[], T]) -> tuple[Sequence, T]:
    """The sequence with its first `frames` frames rendered as PNG and loaded from there, and
    what `alongside()` returned, run in a thread meanwhile; `on_frame(done)` after each frame.
    Frames come from the cache of rendered flights (sim.replay.frame_cache) when an earlier run
    rendered the same ones, else they are rendered into it, or into `folder` when it is not
    writable."""
    first = sequence.image_loader(0)  # compiles the renderer before the workers fork
    key = frame_cache.flight_key(sequence, frames, first)
    cached = frame_cache.lookup(key)
    if cached is not None:
        on_frame(frames)
        return _loaded_from(sequence, cached), alongside()
    staged = frame_cache.staging()
    try:
        result = _rendered_into(staged or folder, sequence, frames, on_frame, alongside)
    except BaseException:
        if staged is not None:
            shutil.rmtree(staged, ignore_errors=True)
        raise
    kept = folder if staged is None else frame_cache.publish(staged, key)
    return _loaded_from(sequence, kept), result


def _rendered_into(folder: Path, sequence: Sequence, frames: int,
                   on_frame: Callable[[int], None], alongside: Callable[[], T]) -> T:
    """Render the first `frames` frames into `folder` on all cores; what `alongside()` returned
    meanwhile."""
    stop = multiprocessing.get_context("fork").Event()
    _RENDER.update(sequence=sequence, folder=folder, stop=stop)
    workers = max(1, min(os.cpu_count() or 1, 4))
    result: list = []
    try:
        # the workers fork before the thread starts: no lock of the thread's is copied
        with _render_pool(workers) as pool:
            thread = threading.Thread(target=lambda: result.append(alongside()),
                                      name="alongside-rendering")
            thread.start()
            try:
                for done, _ in enumerate(pool.imap_unordered(_render, range(frames),
                                                             chunksize=4)):
                    on_frame(done + 1)
            except Exception:
                # the workers end on their sentinel, not the exit's SIGTERM: one killed while
                # it sent a result keeps the result queue's lock, and Pool.terminate() then
                # waits for it forever (1 run in 25 of a failing render hung)
                stop.set()
                pool.close()
                pool.join()
                raise
            pool.close()  # the workers end on their own; the exit's SIGTERM only on an interrupt
            pool.join()
            thread.join()
    finally:
        _RENDER.clear()
    if not result:
        raise RuntimeError("the work alongside rendering failed (see the traceback above)")
    return result[0]


def _loaded_from(sequence: Sequence, folder: Path) -> Sequence:
    """`sequence` with its frames read from the PNG files in `folder`."""
    return dataclasses.replace(sequence, image_loader=lambda i: load_grey(folder / f"{i:06d}.png"))
