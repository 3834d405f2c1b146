"""Link trouble: a UDP port in use, a serial device that is missing, a MAVLink 1 autopilot."""

from __future__ import annotations

import logging
import socket

from daemon_helpers import RunningService, service_config, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import SimAutopilot, configured_options


def test_udp_port_in_use_is_retried_then_served(caplog):
    """udpin on a busy port: warnings and retries; once free, the service listens and answers
    whoever talks to it (TIMESYNC goes back to the sender)."""
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", 0))
    port = blocker.getsockname()[1]
    caplog.set_level(logging.WARNING, logger="sdvl.link")
    run = RunningService(service_config(f"udpin:127.0.0.1:{port}"))
    try:
        assert wait_for(lambda: "Address already in use" in caplog.text, 3.0)
        assert not run.service.link.connected
        blocker.close()
        assert wait_for(lambda: run.service.link.connected, 8.0)
        gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        gcs.settimeout(2.0)
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        gcs.sendto(mav.timesync_encode(0, 42).pack(mav), ("127.0.0.1", port))
        parser = mavlink2.MAVLink(None)
        replies = []
        while not replies:
            for msg in parser.parse_buffer(gcs.recv(4096)) or []:
                if msg.get_type() == "TIMESYNC" and msg.ts1 == 42:
                    replies.append(msg)
        assert replies[0].tc1 > 0
        gcs.close()
    finally:
        assert run.stop() == 0


def test_missing_serial_device_is_retried(caplog):
    caplog.set_level(logging.WARNING, logger="sdvl.link")
    run = RunningService(service_config("serial:/dev/ttySDVL-missing:921600"))
    assert wait_for(lambda: caplog.text.count("cannot open") >= 2, 5.0)
    assert "/dev/ttySDVL-missing" in caplog.text
    assert run.stop() == 0


def test_mavlink1_autopilot_is_warned_about(caplog):
    caplog.set_level(logging.WARNING, logger="sdvl.mavlink")
    with SimAutopilot(configured_options(mavlink1=True, heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url))
        assert wait_for(lambda: run.service.codec.mavlink1_seen, 5.0)
        assert wait_for(lambda: len(sim.messages("ODOMETRY")) > 5, 5.0)
        run.stop()
    assert caplog.text.count("autopilot speaks MAVLink 1") == 1
    assert all(r.msg.get_msgbuf()[0] == 0xFD for r in sim.received)  # we still send MAVLink 2
