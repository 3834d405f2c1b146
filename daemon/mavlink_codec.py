"""pymavlink's MAVLink 2 codec around a byte transport: encode and send, feed and decode.

The parser runs with robust parsing, so garbage becomes bad-data records instead of
exceptions; anything else it raises resets the parser rather than stopping the link.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

log = logging.getLogger("sdvl.mavlink")
MAVLINK1_MAGIC = 0xFE


class _Sink:
    """File-like target for pymavlink's `send`: forwards packed bytes to a writer."""

    def __init__(self, write: Callable[[bytes], bool]):
        self.write_bytes = write
        self.last_ok = False

    def write(self, buf: bytes) -> None:
        self.last_ok = self.write_bytes(bytes(buf))


class MavlinkCodec:
    """One MAVLink 2 endpoint (our system and component id) on a byte writer."""

    def __init__(self, system_id: int, component_id: int, write: Callable[[bytes], bool],
                 on_message: Callable[[object], None]):
        self._sink = _Sink(write)
        self.mav = mavlink2.MAVLink(self._sink, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self.on_message = on_message
        self.bad_frames = 0
        self.unknown = 0  # messages of the autopilot's dialect that common.xml does not define
        self.unpackable = 0  # messages of ours not sent: a value beyond their fields' range
        self._unpackable_logged: set[str] = set()
        self.parser_resets = 0
        self.mavlink1_seen = False
        self.sent: dict[str, int] = {}

    def send(self, msg: object) -> bool:
        """Pack `msg` as MAVLink 2 and write it; True when the transport took it. A message
        with a value its fields cannot carry (beyond float32 or an integer's range) is not
        sent, counted and logged once per kind: a bug upstream, never a reason to stop."""
        name = msg.get_type()
        try:
            self.mav.send(msg)
        except (struct.error, OverflowError, ValueError) as exc:
            self.unpackable += 1
            if name not in self._unpackable_logged:
                self._unpackable_logged.add(name)
                log.error("%s not sent: a value its fields cannot carry (%s); such messages "
                          "are dropped and counted", name, exc)
            return False
        self.sent[name] = self.sent.get(name, 0) + 1
        return self._sink.last_ok

    def feed(self, data: bytes) -> None:
        """Decode whatever complete messages `data` completes and hand each to on_message."""
        try:
            messages = self.mav.parse_buffer(data) or []
        except Exception as exc:  # pymavlink raises assorted errors on hostile input
            self.parser_resets += 1
            log.debug("parser reset after %s", exc)
            self.mav.buf, self.mav.buf_index = bytearray(), 0
            self.mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
            return
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                self.bad_frames += 1
                continue
            if not self.mavlink1_seen and msg.get_msgbuf()[0] == MAVLINK1_MAGIC:
                self.mavlink1_seen = True
                log.warning("autopilot speaks MAVLink 1 (system %d): set its port to MAVLink 2 "
                            "(ArduPilot SERIALx_PROTOCOL=2) or quality, covariance and "
                            "reset_counter are lost", msg.get_srcSystem())
            if msg.get_type().startswith("UNKNOWN_"):  # ArduPilot's EKF_STATUS_REPORT, AHRS...
                self.unknown += 1  # pymavlink gives them no sender: system 0, not a stranger
                continue
            self.on_message(msg)
