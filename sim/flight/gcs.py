"""A ground station on the autopilot's link: it sends what a user's GCS or mission script sends
(COMMAND_LONG arm, DO_SET_MODE, NAV_TAKEOFF, REQUEST_MESSAGE; SET_POSITION_TARGET_LOCAL_NED;
a 1 Hz HEARTBEAT) and keeps what it hears: the autopilot's HEARTBEAT (armed, mode, status),
COMMAND_ACKs, STATUSTEXTs, LOCAL_POSITION_NED, EKF_STATUS_REPORT, and the arrival times of the
companion's vision messages (a router forwards them to the GCS, as mavlink-router does).

It asks for no streams: a stream interval set by the GCS would change what the companion's port
streams too. What it needs polled it asks for once with MAV_CMD_REQUEST_MESSAGE.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot.records import Severity, StatusText

GCS_ID = (255, mavlink2.MAV_COMP_ID_MISSIONPLANNER)
VISION = ("ODOMETRY", "VISION_POSITION_ESTIMATE")
VISION_WINDOW_S = 1.0
# EKF_STATUS_REPORT flags (ardupilotmega.xml EKF_STATUS_FLAGS)
EKF_POS_HORIZ_ABS = ardupilotmega.EKF_POS_HORIZ_ABS
EKF_CONST_POS_MODE = ardupilotmega.EKF_CONST_POS_MODE
# SET_POSITION_TARGET_LOCAL_NED type_mask: use the position only (velocity, acceleration, yaw
# and yaw rate ignored), as ArduPilot's GUIDED position targets from scripts
POSITION_ONLY = 0b110111111000


@dataclass(frozen=True)
class LocalPosition:
    """The autopilot's LOCAL_POSITION_NED and when it arrived."""

    t: float
    position: np.ndarray
    velocity: np.ndarray


class GroundStation:
    """`feed(data, now)` with the link's bytes; commands go out through `write(bytes)`."""

    def __init__(self, write: Callable[[bytes], None], target: tuple[int, int] = (1, 1)):
        self.write = write
        self.target = target
        self.mav = mavlink2.MAVLink(None, srcSystem=GCS_ID[0], srcComponent=GCS_ID[1])
        self._parser = ardupilotmega.MAVLink(None)
        self._parser.robust_parsing = True
        self.heartbeat_t: float | None = None
        self.armed = False
        self.custom_mode: int | None = None
        self.system_status: int | None = None
        self.acks: list[tuple[float, int, int]] = []  # (t, command, result)
        self.texts: list[StatusText] = []  # chunks joined
        self.position: LocalPosition | None = None
        self.ekf_flags: tuple[float, int] | None = None
        self.vision_arrivals: deque[float] = deque()
        self._chunk_id = 0
        self._next_heartbeat = 0.0

    # --- what it hears -----------------------------------------------------------------------

    def feed(self, data: bytes, now: float) -> None:
        """Decode the link's bytes."""
        for msg in self._parser.parse_buffer(data) or []:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                continue
            if kind in VISION:
                self.vision_arrivals.append(now)
            elif msg.get_srcSystem() == self.target[0] and \
                    msg.get_srcComponent() == self.target[1]:
                self._from_autopilot(kind, msg, now)

    def _from_autopilot(self, kind: str, msg: object, now: float) -> None:
        if kind == "HEARTBEAT":
            self.heartbeat_t = now
            self.armed = bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode, self.system_status = msg.custom_mode, msg.system_status
        elif kind == "COMMAND_ACK" and msg.target_system == GCS_ID[0]:
            self.acks.append((now, msg.command, msg.result))
        elif kind == "STATUSTEXT":
            self._text(msg, now)
        elif kind == "LOCAL_POSITION_NED":
            self.position = LocalPosition(now, np.array([msg.x, msg.y, msg.z]),
                                          np.array([msg.vx, msg.vy, msg.vz]))
        elif kind == "EKF_STATUS_REPORT":
            self.ekf_flags = (now, msg.flags)

    def _text(self, msg: object, now: float) -> None:
        """MAVLink 2 chunks of one text share a non-zero id."""
        if msg.id and msg.id == self._chunk_id and msg.chunk_seq > 0 and self.texts:
            last = self.texts[-1]
            self.texts[-1] = StatusText(last.t, last.severity, last.text + msg.text)
            return
        self._chunk_id = msg.id
        self.texts.append(StatusText(now, Severity(msg.severity), msg.text))

    def texts_since(self, t: float,
                    severity: int = mavlink2.MAV_SEVERITY_WARNING) -> list[str]:
        """The texts heard since `t` of at least `severity` (by default the warnings and worse
        that say why something was refused)."""
        return [x.text for x in self.texts if x.t >= t and x.severity <= severity]

    def ack(self, command: int, since: float) -> int | None:
        """The result of the last COMMAND_ACK for `command` since `since` (None: none)."""
        results = [r for t, c, r in self.acks if c == command and t >= since]
        return results[-1] if results else None

    def vision_rate(self, now: float) -> float:
        """Companion vision messages per second over the last VISION_WINDOW_S."""
        while self.vision_arrivals and now - self.vision_arrivals[0] > VISION_WINDOW_S:
            self.vision_arrivals.popleft()
        return len(self.vision_arrivals) / VISION_WINDOW_S

    def has_position(self) -> bool:
        """EKF_STATUS_REPORT: a horizontal position, not the constant-position fallback (what
        ArduCopter's position_ok asks for GUIDED and LOITER)."""
        if self.ekf_flags is None:
            return False
        flags = self.ekf_flags[1]
        return bool(flags & EKF_POS_HORIZ_ABS) and not flags & EKF_CONST_POS_MODE

    # --- what it sends -----------------------------------------------------------------------

    def _send(self, msg: object) -> None:
        self.write(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    def tick(self, now: float) -> None:
        """The GCS HEARTBEAT at 1 Hz."""
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + 1.0
            self._send(self.mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS,
                                                 mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                                                 mavlink2.MAV_STATE_ACTIVE))

    def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG to the autopilot (params 1-7, missing ones 0)."""
        args = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self._send(self.mav.command_long_encode(*self.target, command, 0, *args))

    def request(self, message_id: int) -> None:
        """One message now (MAV_CMD_REQUEST_MESSAGE)."""
        self.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, message_id)

    def set_mode(self, custom_mode: int) -> None:
        self.command(mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                     custom_mode)

    def arm(self) -> None:
        self.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def takeoff(self, height_m: float) -> None:
        self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height_m)

    def go_to(self, ned: np.ndarray, now: float) -> None:
        """A GUIDED position target in the autopilot's local NED frame (from its origin)."""
        self._send(self.mav.set_position_target_local_ned_encode(
            int(now * 1000) & 0xFFFFFFFF, *self.target, mavlink2.MAV_FRAME_LOCAL_NED,
            POSITION_ONLY, *(float(v) for v in ned), 0, 0, 0, 0, 0, 0, 0, 0))
