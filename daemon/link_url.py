"""Autopilot link URLs in pymavlink's forms (and ours), parsed into a LinkSpec.

The meaning of each form follows pymavlink's `mavutil.mavlink_connection` (pymavlink 2.4,
ArduPilot/pymavlink mavutil.py), so a line that works with MAVProxy or a pymavlink script works
here too:

    udpin:ADDR:PORT     listen on ADDR:PORT (0.0.0.0: every interface); replies go to the
                        address heard from last. Use it when the autopilot sends to us: SITL
                        `--serial2 udpclient:IP:PORT`, mavlink-router's UDP client endpoint,
                        MAVProxy `--out IP:PORT`.
    udp:ADDR:PORT       the same as udpin: pymavlink opens `udp:` as a listening socket.
    udpout:HOST:PORT    send to HOST:PORT and take its replies: the other end listens
                        (mavlink-router's UDP server endpoint, an autopilot's UDP server port).
    tcp:HOST:PORT       connect to a TCP server (SITL's tcp:5760/5762/5763, mavlink-router).
    tcpin:ADDR:PORT     accept one TCP client on ADDR:PORT.
    DEVICE,BAUD         a serial port at BAUD, pymavlink's form: /dev/ttyACM0,921600
    DEVICE:BAUD         the same: /dev/serial0:921600
    serial:DEVICE:BAUD  the same, explicitly.

A serial port needs its baud rate: the autopilot's SERIALn_BAUD (ArduPilot, 921 = 921600) or
SER_TELn_BAUD (PX4); over USB the rate is ignored but still written.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from enum import StrEnum

from sdvl.errors import InputError

FORMS = ("udpin:ADDR:PORT (listen), udp:ADDR:PORT (listen, as pymavlink), udpout:HOST:PORT "
         "(send), tcp:HOST:PORT (connect), tcpin:ADDR:PORT (accept), /dev/DEVICE,BAUD, "
         "/dev/DEVICE:BAUD or serial:/dev/DEVICE:BAUD")


class LinkKind(StrEnum):
    """Transport and direction of a link."""

    UDP_IN = "udpin"
    UDP_OUT = "udpout"
    TCP = "tcp"
    TCP_IN = "tcpin"
    SERIAL = "serial"


NETWORK_PREFIXES = {"udpin": LinkKind.UDP_IN, "udp": LinkKind.UDP_IN,
                    "udpout": LinkKind.UDP_OUT, "tcp": LinkKind.TCP, "tcpin": LinkKind.TCP_IN}


@dataclass(frozen=True)
class LinkSpec:
    """A parsed link URL; str() gives its canonical form."""

    kind: LinkKind
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    def __str__(self) -> str:
        if self.kind == LinkKind.SERIAL:
            return f"serial:{self.device}:{self.baud}"
        return f"{self.kind}:{self.host}:{self.port}"

    @property
    def usb(self) -> bool:
        """The autopilot's own USB port (ArduPilot's SERIAL0): a USB CDC ACM device, also when
        named through a /dev/serial/by-id link (a USB-serial adapter is a ttyUSB, a UART)."""
        return self.kind == LinkKind.SERIAL and "ttyACM" in os.path.realpath(self.device)


def _fail(url: str, why: str) -> InputError:
    return InputError(f"mavlink.link '{url}': {why}; accepted forms: {FORMS}")


def _serial(url: str, rest: str) -> LinkSpec:
    """DEVICE,BAUD or DEVICE:BAUD (the last separator: by-path device names contain ':')."""
    sep = "," if "," in rest else ":"
    device, _, baud = rest.rpartition(sep)
    if not device or not baud.isdigit() or int(baud) <= 0:
        raise _fail(url, "a serial port needs its baud rate, e.g. /dev/ttyACM0,921600")
    return LinkSpec(LinkKind.SERIAL, device=device, baud=int(baud))


def _network(url: str, kind: LinkKind, rest: str) -> LinkSpec:
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit():
        raise _fail(url, "expected HOST:PORT after the prefix")
    if not 0 < int(port) < 65536:
        raise _fail(url, "port must be 1..65535")
    return LinkSpec(kind, host=host, port=int(port))


def parse_link_url(url: str) -> LinkSpec:
    """LinkSpec from a URL; InputError naming the accepted forms when it cannot be read."""
    url = url.strip()
    if url.startswith("serial:"):
        return _serial(url, url[len("serial:"):])
    if url.startswith("/"):
        return _serial(url, url)
    prefix, _, rest = url.partition(":")
    if prefix not in NETWORK_PREFIXES:
        raise _fail(url, "unknown form")
    return _network(url, NETWORK_PREFIXES[prefix], rest)
