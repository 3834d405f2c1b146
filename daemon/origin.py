"""Give a GPS-less autopilot its EKF origin, and keep trying until it confirms.

Autopilots drop an origin sent before their EKF is ready, and ArduPilot accepts one only once, so
the origin is resent every interval until GPS_GLOBAL_ORIGIN arrives, and a REQUEST_MESSAGE for
GPS_GLOBAL_ORIGIN goes with each attempt (an autopilot that already has an origin then says so).
MAV_CMD_DO_SET_GLOBAL_ORIGIN is tried first; SET_GPS_GLOBAL_ORIGIN is used when the command is
unsupported or never acknowledged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from daemon.config import OriginConfig
from daemon.messages import MAV_CMD_DO_SET_GLOBAL_ORIGIN

log = logging.getLogger("sdvl.origin")
UNANSWERED_COMMANDS_BEFORE_FALLBACK = 3
SAME_ORIGIN_DEG = 1e-6


class OriginSetter:
    """State: waiting for an autopilot, sending, confirmed. `tick` sends when due."""

    def __init__(self, config: OriginConfig, mav: mavlink2.MAVLink,
                 send: Callable[[object], bool]):
        self.config, self.mav, self.send = config, mav, send
        self.confirmed = False
        self.use_command = True
        self.attempts = 0
        self.unanswered = 0
        self.next_due = 0.0
        self.confirmed_origin: tuple[float, float, float] | None = None

    def restart(self) -> None:
        """After a reboot or a reconnect: the autopilot may have forgotten the origin."""
        self.confirmed, self.use_command, self.unanswered, self.next_due = False, True, 0, 0.0

    def tick(self, now: float, target: tuple[int, int] | None) -> None:
        """Send an attempt when one is due and an autopilot is known (target = sys, comp)."""
        if self.confirmed or target is None or now < self.next_due:
            return
        system, component = target
        lat, lon = (round(v * 1e7) for v in
                    (self.config.latitude_deg, self.config.longitude_deg))
        if self.use_command:
            if self.unanswered >= UNANSWERED_COMMANDS_BEFORE_FALLBACK:
                log.info("origin: DO_SET_GLOBAL_ORIGIN never acknowledged; "
                         "using SET_GPS_GLOBAL_ORIGIN")
                self.use_command = False
            else:
                self.unanswered += 1
        if self.use_command:
            msg = self.mav.command_int_encode(
                system, component, mavlink2.MAV_FRAME_GLOBAL, MAV_CMD_DO_SET_GLOBAL_ORIGIN, 0, 0,
                0, 0, 0, 0, lat, lon, float(self.config.altitude_m))
        else:
            msg = self.mav.set_gps_global_origin_encode(
                system, lat, lon, round(self.config.altitude_m * 1000))
        self.send(msg)
        self.send(self.mav.command_long_encode(
            system, component, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0,
            mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 0, 0, 0, 0, 0, 0))
        self.attempts += 1
        self.next_due = now + self.config.resend_interval_s

    def on_message(self, msg: object) -> str | None:
        """Handle COMMAND_ACK and GPS_GLOBAL_ORIGIN; returns a status text on confirmation."""
        kind = msg.get_type()
        if kind == "COMMAND_ACK" and msg.command == MAV_CMD_DO_SET_GLOBAL_ORIGIN:
            self.unanswered = 0
            if msg.result == mavlink2.MAV_RESULT_UNSUPPORTED:
                log.info("origin: DO_SET_GLOBAL_ORIGIN not supported; using SET_GPS_GLOBAL_ORIGIN")
                self.use_command = False
                self.next_due = 0.0
            return None
        if kind != "GPS_GLOBAL_ORIGIN" or self.confirmed:
            return None
        self.confirmed = True
        got = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
        self.confirmed_origin = got
        want = (self.config.latitude_deg, self.config.longitude_deg)
        if max(abs(got[0] - want[0]), abs(got[1] - want[1])) > SAME_ORIGIN_DEG:
            log.warning("origin: autopilot keeps its own origin %.7f %.7f %.1f m, not ours",
                        *got)
            return "autopilot has another EKF origin"
        log.info("origin: confirmed after %d attempt(s)", self.attempts)
        return "EKF origin set"
