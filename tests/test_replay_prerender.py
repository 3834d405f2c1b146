"""The frames a real-time replay renders first, in forked worker processes, and keeps for the
next run of the same flight."""

from __future__ import annotations

import logging
import os
import signal

import numpy as np
import pytest

from calib.camera import CameraModel
from sim.replay import frame_cache
from sim.replay.prerender import prerendered
from sim.sequence import Sequence

CAMERA = CameraModel(32, 24, 30.0, 30.0, 16.0, 12.0)


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SDVL_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _sigterm_is_default(i: int) -> np.ndarray:
    """Frame i: its first pixel is i, the second 1 when the rendering process ends on SIGTERM."""
    image = np.zeros((24, 32), np.uint8)
    image[0, 0] = i
    image[0, 1] = signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    return image


def _only_the_first(i: int) -> np.ndarray:
    """A renderer that must not be asked for more than frame 0 (the frames are cached)."""
    assert i == 0, f"frame {i} rendered again"
    return _sigterm_is_default(0)


def _flight(loader, frames: int = 10, rate: float = 30.0) -> Sequence:
    return Sequence("ramp", CAMERA, np.arange(frames) / rate, image_loader=loader)


def _render(sequence: Sequence, folder, frames: int = 10) -> tuple[list[np.ndarray], list[int]]:
    done: list[int] = []
    rendered, alongside = prerendered(sequence, folder, frames, done.append, lambda: 42)
    assert alongside == 42
    return [rendered.image_loader(i) for i in range(frames)], done


def test_frames_render_in_workers_that_end_on_sigterm(tmp_path):
    """`sdvl run` leaves SIGTERM only setting a flag; the pool's exit ends idle workers with
    SIGTERM, so a worker that kept that handler never ended (a CI run hung on it)."""
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: None)
    try:
        frames, done = _render(_flight(_sigterm_is_default), tmp_path)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert sorted(done) == list(range(1, 11))
    assert [int(f[0, 0]) for f in frames] == list(range(10))
    assert all(f[0, 1] == 1 for f in frames)


def test_a_second_run_of_the_same_flight_reads_the_kept_frames(tmp_path):
    first, _ = _render(_flight(_sigterm_is_default), tmp_path)
    again, done = _render(_flight(_only_the_first), tmp_path)
    assert done == [10]
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    with pytest.raises(AssertionError, match="rendered again"):  # other frame times: rendered
        _render(_flight(_only_the_first, rate=15.0), tmp_path)


def test_an_unwritable_cache_renders_into_the_callers_folder(tmp_path, cache, caplog):
    cache.parent.mkdir(exist_ok=True)
    cache.write_text("a file where the cache folder should be")
    with caplog.at_level(logging.WARNING, "sdvl.cache"):
        frames, _ = _render(_flight(_sigterm_is_default), tmp_path)
    assert [int(f[0, 0]) for f in frames] == list(range(10))
    assert sorted(p.name for p in tmp_path.glob("*.png"))[0] == "000000.png"
    assert "SDVL_CACHE_DIR" in caplog.text


def test_only_the_newest_flights_are_kept(tmp_path, monkeypatch):
    monkeypatch.setattr(frame_cache, "IN_USE_S", 0.0)
    for rate in range(1, frame_cache.KEEP_FLIGHTS + 3):
        _render(_flight(_sigterm_is_default, rate=float(rate)), tmp_path, frames=2)
        flights = frame_cache.cache_root().iterdir()
        for n, path in enumerate(sorted(flights, key=os.path.getmtime)):
            os.utime(path, (n, n))  # in the order they were made, all long ago
    assert len(list(frame_cache.cache_root().iterdir())) == frame_cache.KEEP_FLIGHTS
