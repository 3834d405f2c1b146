"""Shared fixtures: where the read-only test data lives (SDVL_DATA overrides ../shared/data)."""

from __future__ import annotations

import os
import platform
import signal
import subprocess
import sys
from pathlib import Path

# numba compiles for the machine's CPU, and AVX-512 code rounds differently from AVX2 code:
# tum_fr1_rpy's re-initialised map joins its old one with AVX2 code and not with AVX-512 code
# (RESULTS.md, tracker-kf-baseline). The tests compile for one x86-64 target, so every CI
# machine gives the same results; set before anything imports numba.
if platform.machine() == "x86_64":
    os.environ.setdefault("NUMBA_CPU_NAME", "haswell")

import pytest

from sim.shared_data import shared_data_dir

DATA_DIR = shared_data_dir()
REAL_SEQUENCES = ("tum_fr1_rpy", "vamr_ex01_checkerboard736", "kitti00_first200")


PRECOMPILE_TIMEOUT_S = 1200  # 43 s on a clean clone here; a small board is several times slower


def pytest_configure(config: pytest.Config) -> None:
    """With xdist workers, fill numba's cache once before they start (tests/precompile.py, its
    parts side by side), so they load the common kernels instead of each compiling them."""
    if (hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None)
            or config.option.collectonly or config.option.help):
        return
    script = Path(__file__).with_name("precompile.py")
    parts = [subprocess.Popen([sys.executable, str(script), part]) for part in ("tracker", "scene")]
    try:
        failed = any([p.wait(PRECOMPILE_TIMEOUT_S) != 0 for p in parts])
    except subprocess.TimeoutExpired:
        for p in parts:
            p.kill()
        pytest.exit(f"compiling the numba kernels took over {PRECOMPILE_TIMEOUT_S} s", 1)
    if failed:
        pytest.exit("compiling the numba kernels before the workers start failed (above)", 1)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The shared data folder; the test fails loudly if it is missing (CI must have it)."""
    assert DATA_DIR.is_dir(), f"test data not found at {DATA_DIR}; set SDVL_DATA"
    return DATA_DIR


@pytest.fixture(autouse=True)
def _signal_handlers_restored():
    """A test that runs `sdvl run` in this process installs its signal handlers; the next test
    (and the pool workers it forks) gets the process's own back."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


@pytest.fixture(scope="session", autouse=True)
def _frame_cache_of_this_run(tmp_path_factory):
    """Rendered flights are kept in this run's temporary folder, shared by the xdist workers,
    not in the user's cache."""
    before = os.environ.get("SDVL_CACHE_DIR")
    os.environ["SDVL_CACHE_DIR"] = str(tmp_path_factory.getbasetemp().parent / "frame-cache")
    yield
    if before is None:
        del os.environ["SDVL_CACHE_DIR"]
    else:
        os.environ["SDVL_CACHE_DIR"] = before


@pytest.fixture
def quick_autopilot_probe(monkeypatch):
    """Shorter listening, pre-arm wait and stream settling for `sdvl check-autopilot` than a
    real autopilot gets: the simulated one streams at once and answers within milliseconds."""
    from daemon import autopilot_probe, streams

    monkeypatch.setattr(autopilot_probe, "LISTEN_S", 1.0)
    monkeypatch.setattr(autopilot_probe, "PREARM_WAIT_S", 0.5)
    monkeypatch.setattr(streams, "SETTLE_S", 1.5)
