"""`sdvl run` as systemd sees it: signals from the first moment, SIGHUP, STOPPING=1, exit codes,
and a disk that cannot take the numba cache or the log."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from calib.camera import CameraModel
from calib.camera_yaml import save_camera
from daemon import logs, numba_cache
from sim.autopilot import SimAutopilot, SimOptions

SIGTERM_BIT = 1 << (signal.SIGTERM - 1)


def receiver(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(10.0)
    return sock


def notifications(sock: socket.socket, timeout: float = 0.3) -> list[str]:
    """Every datagram still queued."""
    sock.settimeout(timeout)
    got = []
    try:
        while True:
            got.append(sock.recv(4096).decode())
    except TimeoutError:
        return got


def start(config: Path, notify: Path | None = None, **env: str) -> subprocess.Popen:
    environ = {**os.environ, **env}
    if notify is not None:
        environ["NOTIFY_SOCKET"] = str(notify)
    return subprocess.Popen([sys.executable, "-m", "sdvl.cli", "run", "--config", str(config)],
                            env=environ, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def catches_sigterm(pid: int) -> bool:
    """Whether the process has its own SIGTERM handler (/proc/PID/status SigCgt)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    caught = next(line for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(int(caught.split()[1], 16) & SIGTERM_BIT)


def test_sigterm_as_soon_as_the_process_runs_is_a_clean_stop(tmp_path):
    """SIGTERM sent the moment the handler is in place (long before the service runs): exit
    code 0, no traceback, STOPPING=1."""
    notify = receiver(tmp_path / "notify")
    config = tmp_path / "sdvl.toml"
    config.write_text('[camera]\nsource = "testpattern"\n')
    proc = start(config, tmp_path / "notify")
    t0 = time.monotonic()
    while not catches_sigterm(proc.pid) and proc.poll() is None:
        time.sleep(0.002)
    installed_s = time.monotonic() - t0
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    assert "STOPPING=1" in notifications(notify)
    print(f"\nSIGTERM handler installed {installed_s * 1e3:.0f} ms after the start")


def test_sighup_while_starting_is_ignored_and_said(tmp_path):
    """SIGHUP the moment the handlers are in place (systemd's reload during the start): the
    service says it is ignored and starts as if it had not come."""
    notify = receiver(tmp_path / "notify")
    config = tmp_path / "sdvl.toml"
    config.write_text('[camera]\nsource = "testpattern"\n')
    proc = start(config, tmp_path / "notify")
    try:
        while not catches_sigterm(proc.pid) and proc.poll() is None:
            time.sleep(0.002)
        proc.send_signal(signal.SIGHUP)
        notify.settimeout(60)
        assert notify.recv(4096).decode().startswith("READY=1")
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "SIGHUP while starting" in stderr and "ignored" in stderr
    assert "Traceback" not in stderr


def test_sighup_rereads_the_config_and_sigterm_stops(tmp_path):
    notify = receiver(tmp_path / "notify")
    config = tmp_path / "sdvl.toml"
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        config.write_text(f'[camera]\nsource = "testpattern"\n[mavlink]\nlink = "{sim.url}"\n')
        proc = start(config, tmp_path / "notify")
        try:
            notify.settimeout(60)
            assert notify.recv(4096).decode().startswith("READY=1")
            config.write_text(f'[camera]\nsource = "testpattern"\nfps = 20.0\n[mavlink]\n'
                              f'link = "{sim.url}"\n[service]\nlog_level = "warning"\n')
            proc.send_signal(signal.SIGHUP)
            time.sleep(1.0)
            config.write_text("[mavlink]\nmax_rate_hz = nan\n")  # broken: kept running
            proc.send_signal(signal.SIGHUP)
            time.sleep(1.0)
            assert proc.poll() is None
            proc.send_signal(signal.SIGTERM)
            _, stderr = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
    got = notifications(notify)
    assert proc.returncode == 0, stderr
    assert "applied: service.log_level; need a restart (systemctl restart sdvl-companion): " \
           "camera.fps" in stderr
    assert "mavlink.max_rate_hz must be a finite number" in stderr
    assert "the running configuration is kept" in stderr
    assert sum(g.startswith("RELOADING=1") for g in got) == 2
    assert "STOPPING=1" in got and "Traceback" not in stderr


def test_calibration_that_does_not_fit_the_frames_is_exit_2_before_ready(tmp_path):
    folder = tmp_path / "rec"
    folder.mkdir()
    rng = np.random.default_rng(1)
    for k in range(90):  # 3 s at 30 fps: long enough to be the calibration's fault
        cv2.imwrite(str(folder / f"{k:03d}.png"), rng.integers(0, 255, (48, 64), np.uint8))
    save_camera(CameraModel(640, 400, 500.0, 500.0, 320.0, 200.0), tmp_path / "camera.yaml")
    notify = receiver(tmp_path / "notify")
    config = tmp_path / "sdvl.toml"
    config.write_text(f'[camera]\nsource = "{folder}"\ncalibration = "{tmp_path}/camera.yaml"\n'
                      '[mavlink]\nlink = "udpout:127.0.0.1:9"\n')
    proc = start(config, tmp_path / "notify")
    _, stderr = proc.communicate(timeout=60)
    got = notifications(notify)
    assert proc.returncode == 2, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("ERROR")]
    assert len(errors) == 1 and "frames are 64x48 but the calibration is 640x400" in errors[0]
    assert "Traceback" not in stderr
    assert not any(g.startswith("READY=1") for g in got) and "STOPPING=1" in got


# --- the disk ------------------------------------------------------------------------------

PROBE = """
import logging, sys
from daemon import numba_cache
logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
cached = numba_cache.prepare()
from numba import njit

@njit(cache=True)
def twice(x):
    return 2 * x

print("result", twice(21), "cached", cached)
"""


def can_mount_tmpfs() -> bool:
    return shutil.which("unshare") is not None and subprocess.run(
        ["unshare", "-rm", "true"], capture_output=True).returncode == 0


@pytest.mark.skipif(not can_mount_tmpfs(), reason="needs unshare -rm (user mount namespaces)")
@pytest.mark.parametrize("disk", ["full", "read-only"])
def test_numba_cache_on_a_full_or_read_only_filesystem_compiles_in_memory(tmp_path, disk):
    """A 64 kB tmpfs, filled up or mounted read-only, as NUMBA_CACHE_DIR: the kernel still
    runs, with one warning."""
    mount = tmp_path / "cache"
    mount.mkdir()
    options = "size=64k" + (",ro" if disk == "read-only" else "")
    fill = f"head -c 1M /dev/zero > {mount}/fill 2>/dev/null; " if disk == "full" else ""
    shell = (f"mount -t tmpfs -o {options} tmpfs {mount} && {fill}"
             f"exec {sys.executable} {tmp_path}/probe.py")
    (tmp_path / "probe.py").write_text(PROBE)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(mount)}
    proc = subprocess.run(["unshare", "-rm", "sh", "-c", shell], env=env,
                          cwd=Path(__file__).resolve().parents[1], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "result 42 cached False" in proc.stdout
    warnings = [line for line in proc.stderr.splitlines() if line.startswith("WARNING")]
    assert len(warnings) == 1 and "compiling the kernels in memory" in warnings[0]


def test_numba_cache_that_fills_up_later_is_one_warning(tmp_path, caplog):
    """The probe passed, then saving a kernel fails with ENOSPC: the kernel runs anyway."""
    from numba import njit
    from numba.core import caching

    numba_cache.prepare()
    numba_cache._WARNED.clear()
    save = caching.IndexDataCacheFile.save

    def full(self, key, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    caplog.set_level(logging.WARNING, logger="sdvl.numba")
    caching.IndexDataCacheFile.save = full
    try:
        @njit(cache=True)
        def thrice(x):
            return 3 * x

        @njit(cache=True)
        def four_times(x):
            return 4 * x

        assert thrice(5) == 15 and four_times(5) == 20
    finally:
        caching.IndexDataCacheFile.save = save
    saves = [r for r in caplog.records if "cannot save" in r.getMessage()]
    assert len(saves) == 1 and "No space left" in saves[0].getMessage()


class Lines:
    """A stream that keeps what is written."""

    def __init__(self) -> None:
        self.text: list[str] = []

    def write(self, text: str) -> None:
        self.text.append(text)

    def flush(self) -> None:
        """Nothing buffered."""


def test_logging_to_a_full_disk_drops_lines_and_counts_them():
    full = open("/dev/full", "w", buffering=1)  # noqa: SIM115 (every write: ENOSPC)
    handler = logs.DroppingHandler(full)
    log = logging.getLogger("sdvl.test-full-disk")
    log.addHandler(handler)
    log.propagate = False
    try:
        for k in range(5):
            log.warning("line %d", k)
    finally:
        log.removeHandler(handler)
        with contextlib.suppress(OSError):
            full.close()
    assert handler.dropped_total == 5
    handler.stream = Lines()  # the disk has room again
    handler.emit(logging.LogRecord("x", logging.WARNING, __file__, 1, "back", None, None))
    assert "5 log line(s) could not be written" in handler.stream.text[0]
    assert "back" in handler.stream.text[0]


def test_sdvl_run_with_its_log_on_a_full_disk_keeps_running(tmp_path):
    notify = receiver(tmp_path / "notify")
    config = tmp_path / "sdvl.toml"
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim, open("/dev/full", "w") as full:
        config.write_text(f'[camera]\nsource = "testpattern"\n[mavlink]\nlink = "{sim.url}"\n'
                          '[service]\nstatus_interval_s = 0.3\n')
        env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify")}
        proc = subprocess.Popen([sys.executable, "-m", "sdvl.cli", "run", "--config",
                                 str(config)], env=env, stderr=full, stdout=full)
        try:
            notify.settimeout(60)
            assert notify.recv(4096).decode().startswith("READY=1")
            status = notify.recv(4096).decode()
            time.sleep(0.5)
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 0 and "log lines lost" in status
