"""Link URLs: pymavlink's forms and ours, what each means, and the one-line error."""

from __future__ import annotations

import socket

import pytest
from daemon_helpers import RunningService, service_config, wait_for
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from daemon.config import config_from_dict, load_config
from daemon.link_url import LinkKind, parse_link_url
from sdvl.errors import InputError


@pytest.mark.parametrize(("url", "kind", "where", "canonical"), [
    ("udpin:0.0.0.0:14550", LinkKind.UDP_IN, ("0.0.0.0", 14550), "udpin:0.0.0.0:14550"),
    ("udp:127.0.0.1:14560", LinkKind.UDP_IN, ("127.0.0.1", 14560), "udpin:127.0.0.1:14560"),
    ("udpout:10.0.0.2:14550", LinkKind.UDP_OUT, ("10.0.0.2", 14550), "udpout:10.0.0.2:14550"),
    ("tcp:localhost:5763", LinkKind.TCP, ("localhost", 5763), "tcp:localhost:5763"),
    ("tcpin:0.0.0.0:5770", LinkKind.TCP_IN, ("0.0.0.0", 5770), "tcpin:0.0.0.0:5770"),
    ("/dev/ttyACM0,921600", LinkKind.SERIAL, ("/dev/ttyACM0", 921600),
     "serial:/dev/ttyACM0:921600"),
    ("/dev/serial0:57600", LinkKind.SERIAL, ("/dev/serial0", 57600), "serial:/dev/serial0:57600"),
    ("serial:/dev/ttyAMA0:921600", LinkKind.SERIAL, ("/dev/ttyAMA0", 921600),
     "serial:/dev/ttyAMA0:921600"),
    ("serial:/dev/ttyAMA0,115200", LinkKind.SERIAL, ("/dev/ttyAMA0", 115200),
     "serial:/dev/ttyAMA0:115200"),
    # by-path names contain ':'; the baud rate is after the last one
    ("/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0:921600", LinkKind.SERIAL,
     ("/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0", 921600),
     "serial:/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0:921600"),
])
def test_link_url_forms(url, kind, where, canonical):
    spec = parse_link_url(url)
    assert spec.kind == kind
    got = (spec.device, spec.baud) if kind == LinkKind.SERIAL else (spec.host, spec.port)
    assert got == where
    assert str(spec) == canonical
    assert parse_link_url(str(spec)) == spec


@pytest.mark.parametrize(("prefix", "listens"), [("udp", True), ("udpin", True),
                                                 ("udpout", False)])
def test_udp_direction_is_pymavlinks(prefix, listens):
    """Each UDP prefix means what pymavlink's mavlink_connection makes of it."""
    ours = parse_link_url(f"{prefix}:127.0.0.1:14599").kind == LinkKind.UDP_IN
    conn = mavutil.mavlink_connection(f"{prefix}:127.0.0.1:0" if listens else
                                      f"{prefix}:127.0.0.1:14599")
    try:
        assert conn.udp_server == listens == ours
    finally:
        conn.close()


def test_usb_devices_are_recognised(tmp_path):
    assert parse_link_url("/dev/ttyACM0,115200").usb
    by_id = tmp_path / "usb-ArduPilot_CubeOrange_1-if00"
    by_id.symlink_to("/dev/ttyACM1")
    assert parse_link_url(f"{by_id},115200").usb
    adapter = tmp_path / "usb-FTDI_FT232R_USB_UART_A50285BI-if00-port0"
    adapter.symlink_to("/dev/ttyUSB0")
    assert not parse_link_url(f"{adapter},921600").usb
    assert not parse_link_url("/dev/ttyAMA0,921600").usb
    assert not parse_link_url("tcp:localhost:5760").usb


@pytest.mark.parametrize(("url", "why"), [
    ("udpout:host", "expected HOST:PORT"),
    ("tcp:host:99999", "port must be 1..65535"),
    ("/dev/ttyACM0", "a serial port needs its baud rate"),
    ("serial:/dev/ttyAMA0:fast", "a serial port needs its baud rate"),
    ("udpbcast:1.2.3.4:5", "unknown form"),
    ("127.0.0.1:14550", "unknown form"),
])
def test_bad_link_urls_list_the_accepted_forms(url, why):
    with pytest.raises(InputError) as err:
        parse_link_url(url)
    text = str(err.value)
    assert text.startswith(f"mavlink.link '{url}': {why}")
    for form in ("udpin:ADDR:PORT", "udp:ADDR:PORT", "udpout:HOST:PORT", "tcp:HOST:PORT",
                 "tcpin:ADDR:PORT", "/dev/DEVICE,BAUD", "serial:/dev/DEVICE:BAUD"):
        assert form in text


def test_a_bad_link_stops_the_config_with_its_path(tmp_path):
    path = tmp_path / "sdvl.toml"
    path.write_text('[mavlink]\nlink = "udp:127.0.0.1"\n')
    with pytest.raises(InputError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: mavlink.link 'udp:127.0.0.1'")
    assert config_from_dict({"mavlink": {"link": "udp:127.0.0.1:14550"}})


def _timesync_reply(sock: socket.socket, send) -> mavlink2.MAVLink_timesync_message:
    """Send a TIMESYNC request with `send` and read the service's answer from `sock`."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    parser = mavlink2.MAVLink(None)
    send(mav.timesync_encode(0, 42).pack(mav))
    while True:
        for msg in parser.parse_buffer(sock.recv(4096)) or []:
            if msg.get_type() == "TIMESYNC" and msg.ts1 == 42:
                return msg


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_udp_prefix_listens_and_answers_the_sender():
    port = _free_port(socket.SOCK_DGRAM)
    run = RunningService(service_config(f"udp:127.0.0.1:{port}"))
    try:
        assert wait_for(lambda: run.service.link.connected, 5.0)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as autopilot:
            autopilot.settimeout(3.0)
            reply = _timesync_reply(autopilot,
                                    lambda b: autopilot.sendto(b, ("127.0.0.1", port)))
        assert reply.tc1 > 0
    finally:
        assert run.stop() == 0


def test_tcpin_accepts_a_client_and_a_newer_one_replaces_it():
    port = _free_port(socket.SOCK_STREAM)
    run = RunningService(service_config(f"tcpin:127.0.0.1:{port}"))
    try:
        assert wait_for(lambda: run.service.link.connected, 5.0)
        for _ in range(2):  # the second client takes over from the first
            with socket.create_connection(("127.0.0.1", port), timeout=3.0) as client:
                assert _timesync_reply(client, client.sendall).tc1 > 0
    finally:
        assert run.stop() == 0
