"""Where the shared data is looked for (sim/shared_data.py)."""

from __future__ import annotations

from pathlib import Path

from sim.shared_data import CHECKOUT, shared_data_dir


def test_sdvl_data_wins_and_an_empty_one_means_unset(monkeypatch, tmp_path):
    monkeypatch.setenv("SDVL_DATA", str(tmp_path))
    assert shared_data_dir() == tmp_path
    monkeypatch.setenv("SDVL_DATA", "")  # as a systemd `Environment=SDVL_DATA=` line leaves it
    assert shared_data_dir() == CHECKOUT.parent / "shared" / "data" != Path(".")
    monkeypatch.delenv("SDVL_DATA")
    assert shared_data_dir() == CHECKOUT.parent / "shared" / "data"
