"""Frames rendered before a real-time replay starts: a synthetic flight renders each frame on
the fly (tens of milliseconds a frame), which a real camera does not do on the companion's CPU,
so in real time the renderer would fall behind the flight's own clock. The frames are rendered
by all cores into a temporary folder first and read back like a recorded sequence's."""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
from pathlib import Path

import cv2

from sim.sequence import Sequence, load_grey

_RENDER: dict = {}  # the sequence and folder the forked workers render from


def renders_on_the_fly(sequence: object) -> bool:
    """Synthetic flights (sim.synth) name their preset in extras."""
    return "preset" in getattr(sequence, "extras", {})


def _render(i: int) -> int:
    sequence, folder = _RENDER["sequence"], _RENDER["folder"]
    cv2.imwrite(str(folder / f"{i:06d}.png"), sequence.image_loader(i))
    return i


def prerendered(sequence: Sequence, folder: Path, frames: int,
                on_frame=lambda done: None) -> Sequence:
    """The sequence with its first `frames` frames rendered into `folder` (PNG) and loaded from
    there; `on_frame(done)` after each."""
    _RENDER.update(sequence=sequence, folder=folder)
    sequence.image_loader(0)  # compile the renderer once, before the workers fork
    workers = max(1, min(os.cpu_count() or 1, 4))
    try:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            for done, _ in enumerate(pool.imap_unordered(_render, range(frames), chunksize=4)):
                on_frame(done + 1)
    finally:
        _RENDER.clear()
    return dataclasses.replace(sequence,
                               image_loader=lambda i: load_grey(folder / f"{i:06d}.png"))
