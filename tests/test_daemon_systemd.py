"""Running under systemd: the unit file, sd_notify datagrams, SIGTERM within 2 s."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from daemon.sdnotify import Notifier
from sim.autopilot import SimAutopilot, configured_options

UNIT = Path(__file__).resolve().parents[1] / "systemd" / "sdvl-companion.service"
INSTALLED_SDVL = "/opt/sdvl/venv/bin/sdvl"


def unit_settings() -> dict[str, list[str]]:
    settings: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.startswith(("#", "[")):
            key, value = line.split("=", 1)
            settings.setdefault(key, []).append(value)
    return settings


def test_unit_has_what_the_service_needs():
    s = unit_settings()
    assert s["Type"] == ["notify"] and s["Restart"] == ["on-failure"]
    assert s["RestartPreventExitStatus"] == ["2"]  # bad config: no restart loop
    assert int(s["WatchdogSec"][0]) > 0
    assert s["User"] == ["sdvl"] and set(s["SupplementaryGroups"][0].split()) >= {"dialout",
                                                                                "video"}
    assert s["CPUQuota"] and s["MemoryMax"] and s["ProtectSystem"] == ["strict"]
    assert s["NoNewPrivileges"] == ["yes"] and s["DevicePolicy"] == ["closed"]
    assert "MemoryDenyWriteExecute" not in s  # numba needs executable memory
    assert s["ExecStart"][0].startswith(INSTALLED_SDVL + " run --config ")


@pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                    reason="systemd-analyze not installed (Debian package 'systemd'; CI "
                           "installs it)")
def test_systemd_analyze_verify_accepts_the_unit(tmp_path):
    # verify checks that ExecStart exists: point it at this checkout's sdvl instead of the
    # installed location, nothing else changes
    sdvl = Path(sys.executable).with_name("sdvl")
    assert sdvl.exists()
    unit = tmp_path / UNIT.name
    unit.write_text(UNIT.read_text().replace(INSTALLED_SDVL, str(sdvl)))
    proc = subprocess.run(["systemd-analyze", "verify", "--man=no", str(unit)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert UNIT.name not in proc.stdout + proc.stderr, proc.stdout + proc.stderr


def receiver(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(10.0)
    return sock


def test_notifier_sends_datagrams(tmp_path):
    sock = receiver(tmp_path / "notify")
    notifier = Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "4000000"})
    assert notifier.enabled and notifier.watchdog_interval_s == 2.0
    assert notifier.notify("READY=1", "STATUS=hello")
    assert sock.recv(4096) == b"READY=1\nSTATUS=hello"
    notifier.close()
    assert not Notifier({}).enabled and not Notifier({}).notify("READY=1")


def test_notifier_abstract_socket():
    name = f"sdvl-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(5.0)
    assert Notifier({"NOTIFY_SOCKET": "@" + name}).notify("WATCHDOG=1")
    assert sock.recv(100) == b"WATCHDOG=1"


def test_sdvl_run_under_notify_socket_and_sigterm(tmp_path):
    """The real `sdvl run` (real tracker, test-pattern camera) against the simulated autopilot:
    READY=1, WATCHDOG=1 and STATUS= arrive; SIGTERM stops it cleanly before systemd would
    kill it (the unit's TimeoutStopSec; 0.06 s on an idle machine, 1.0 s with 20 busy loops,
    when SIGTERM comes during the first frame and the tracking thread is left after
    THREAD_JOIN_S)."""
    notify = receiver(tmp_path / "notify")
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        config = tmp_path / "sdvl.toml"
        config.write_text(f'[camera]\nsource = "testpattern"\n[mavlink]\nlink = "{sim.url}"\n'
                          '[service]\nstatus_interval_s = 0.5\n')
        env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify"),
               "WATCHDOG_USEC": "600000"}
        proc = subprocess.Popen([sys.executable, "-m", "sdvl.cli", "run", "--config", str(config)],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        try:
            notify.settimeout(60.0)  # imports and the numba cache: seconds on a loaded machine
            got = [notify.recv(4096).decode()]
            assert got[0].startswith("READY=1\nSTATUS=")
            while not any("WATCHDOG=1" in g for g in got):
                got.append(notify.recv(4096).decode())
            assert any("STATUS=" in g and "frames" in g for g in got[1:])
            time.sleep(0.5)
            start = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
            stop_s = time.monotonic() - start
        finally:
            if proc.poll() is None:
                proc.kill()
        stderr = proc.stderr.read()
        heartbeats = sim.messages("HEARTBEAT")
    assert proc.returncode == 0, stderr
    assert stop_s < float(unit_settings()["TimeoutStopSec"][0])
    notify.settimeout(0.5)
    while "STOPPING=1" not in got[-1]:
        got.append(notify.recv(4096).decode())
    assert "Traceback" not in stderr
    assert "service stopped" in stderr.splitlines()[-1]
    assert heartbeats and heartbeats[0].msg.get_srcComponent() == 197, stderr
