"""Arrays the simulator keeps on disk between runs (sim/disk_cache.py)."""

from __future__ import annotations

import logging

import numpy as np

from sim import disk_cache


def test_an_array_is_computed_once_then_read(tmp_path, monkeypatch):
    monkeypatch.setenv("SDVL_CACHE_DIR", str(tmp_path))
    calls = []

    def compute():
        calls.append(1)
        return np.arange(6.0).reshape(2, 3)

    first = disk_cache.cached_array("things", "k", compute)
    again = disk_cache.cached_array("things", "k", compute)
    assert len(calls) == 1 and np.array_equal(first, again)
    assert [p.name for p in (tmp_path / "things").iterdir()] == ["k.npy"]


def test_a_corrupt_entry_is_computed_again(tmp_path, monkeypatch):
    monkeypatch.setenv("SDVL_CACHE_DIR", str(tmp_path))
    (tmp_path / "things").mkdir()
    (tmp_path / "things" / "k.npy").write_bytes(b"\x93NUMPY garbage")
    value = disk_cache.cached_array("things", "k", lambda: np.ones(3))
    assert np.array_equal(value, np.ones(3))
    assert np.array_equal(np.load(tmp_path / "things" / "k.npy"), np.ones(3))


def test_an_unwritable_cache_computes_and_warns_once(tmp_path, monkeypatch, caplog):
    (tmp_path / "file").write_text("not a folder")
    monkeypatch.setenv("SDVL_CACHE_DIR", str(tmp_path / "file"))
    with caplog.at_level(logging.WARNING, "sdvl.cache"):
        for _ in range(2):
            assert np.array_equal(disk_cache.cached_array("things", "k", lambda: np.ones(2)),
                                  np.ones(2))
    assert caplog.text.count("SDVL_CACHE_DIR") == 1
