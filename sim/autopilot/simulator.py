"""A simulated autopilot that talks MAVLink 2 to the companion over UDP, TCP or a pty.

It streams what a flight controller streams (HEARTBEAT, ATTITUDE, IMU, DISTANCE_SENSOR, baro /
altitude, SYSTEM_TIME, TIMESYNC requests), handles the EKF origin like ArduPilot (accepted only
once, and only once its EKF is ready; PX4 flavour accepts it whenever), answers parameter reads,
and records every message it receives with its arrival time on CLOCK_MONOTONIC. It can lose the
link or reboot on request. It runs in its own thread.
"""

from __future__ import annotations

import contextlib
import logging
import select
import struct
import threading
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_params import wire_value
from daemon.messages import MAV_CMD_DO_SET_GLOBAL_ORIGIN
from sim.autopilot.params import ARDUPILOT_PARAMS, PX4_PARAMS
from sim.autopilot.ports import open_port
from sim.autopilot.vehicle import Vehicle, sensor_message
from sim.trajectory import Trajectory

log = logging.getLogger("sdvl.sim.autopilot")
VISION_MESSAGES = ("ODOMETRY", "VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE")
AUTOPILOT_TYPE = {"ardupilot": mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                  "px4": mavlink2.MAV_AUTOPILOT_PX4}
DEFAULT_STREAMS = {"ardupilot": {"ATTITUDE": 20, "SCALED_IMU": 50, "DISTANCE_SENSOR": 10,
                                 "SCALED_PRESSURE": 10},
                   "px4": {"ATTITUDE": 20, "HIGHRES_IMU": 50, "DISTANCE_SENSOR": 10,
                           "ALTITUDE": 10}}


@dataclass
class Received:
    """One message from the companion and when it arrived (monotonic seconds)."""

    t: float
    msg: object


@dataclass
class SimOptions:
    """How the simulated autopilot behaves."""

    flavour: str = "ardupilot"  # or "px4"
    port: str = "udp"  # "udp", "tcp" or "pty"
    system_id: int = 1
    ekf_ready_after_s: float = 0.0  # origin requests before this are refused (ArduPilot)
    supports_origin_command: bool = True  # False: MAV_CMD_DO_SET_GLOBAL_ORIGIN is UNSUPPORTED
    timesync_hz: float = 10.0
    heartbeat_hz: float = 1.0
    streams: dict | None = None  # message name -> Hz; None: the flavour's defaults
    params: dict | None = None  # name -> (value, MAV_PARAM_TYPE); None: a vision-ready set
    mavlink1: bool = False  # frame our messages as MAVLink 1 (a misconfigured port)
    trajectory: Trajectory | None = None
    param_overrides: dict = field(default_factory=dict)  # name -> value


class SimAutopilot:
    """Start with `start()` (or as a context manager); the companion connects to `url`."""

    def __init__(self, options: SimOptions | None = None):
        self.opt = options or SimOptions()
        self.port = open_port(self.opt.port)
        self.url = self.port.url
        self.mav = mavlink2.MAVLink(None, srcSystem=self.opt.system_id, srcComponent=1)
        self.mav.robust_parsing = True
        self.vehicle = Vehicle(self.opt.trajectory)
        table = self.opt.params if self.opt.params is not None else (
            ARDUPILOT_PARAMS if self.opt.flavour == "ardupilot" else PX4_PARAMS)
        self.params = dict(table)
        for name, value in self.opt.param_overrides.items():
            kind = self.params.get(name, (0, mavlink2.MAV_PARAM_TYPE_REAL32))[1]
            self.params[name] = (value, kind)
        self.streams = dict(self.opt.streams if self.opt.streams is not None
                            else DEFAULT_STREAMS[self.opt.flavour])
        self.received: list[Received] = []
        self.timesync_rtts: list[float] = []
        self.origin: tuple[int, int, int] | None = None
        self.origin_attempts: list[tuple[float, str, bool]] = []  # (t, kind, accepted)
        self.bad_frames = 0
        self.skipped_messages = 0  # stream messages whose values did not fit the message
        self._skip_logged: set[str] = set()
        self.sent_count: dict[str, int] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-autopilot", daemon=True)
        self._silent_until = 0.0
        self._boot()

    # --- control from tests ---------------------------------------------------------------

    def start(self) -> SimAutopilot:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self.port.close()

    def __enter__(self) -> SimAutopilot:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def lose_link(self, seconds: float) -> None:
        """Neither send nor hear anything for `seconds` (a cable fault, radio fade)."""
        with self._lock:
            self._silent_until = time.monotonic() + seconds
            self._reboot_on_resume = False

    def reboot(self, downtime_s: float = 0.5) -> None:
        """Go silent, then come back with boot time 0, no origin and an EKF not yet ready."""
        with self._lock:
            self._silent_until = time.monotonic() + downtime_s
            self._reboot_on_resume = True

    def inject(self, data: bytes) -> None:
        """Write raw bytes to the companion (garbage, truncated frames)."""
        with self._lock:
            self.port.write(data)

    def messages(self, name: str, since: float = 0.0) -> list[Received]:
        """Received messages of one type, arrived at or after `since`."""
        with self._lock:
            return [r for r in self.received if r.msg.get_type() == name and r.t >= since]

    @property
    def vision(self) -> list[Received]:
        with self._lock:
            return [r for r in self.received if r.msg.get_type() in VISION_MESSAGES]

    # --- the thread -----------------------------------------------------------------------

    def _boot(self) -> None:
        now = time.monotonic()
        self.boot_time = now
        self.origin = None
        self.ekf_ready_at = now + self.opt.ekf_ready_after_s
        self._reboot_on_resume = False
        self._due = {name: now for name in [*self.streams, "HEARTBEAT", "TIMESYNC",
                                            "SYSTEM_TIME"]}

    def _rates(self) -> dict[str, float]:
        return {**self.streams, "HEARTBEAT": self.opt.heartbeat_hz,
                "TIMESYNC": self.opt.timesync_hz, "SYSTEM_TIME": 1.0}

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError, ValueError):
                select.select([self.port], [], [], 0.002)
            data = self.port.read()
            now = time.monotonic()
            with self._lock:
                silent = now < self._silent_until
                if not silent and self._reboot_on_resume:
                    self._boot()
                if data and not silent:
                    self._receive(data, now)
                if not silent:
                    self._stream(now)

    def _send(self, msg: object) -> None:
        buf = msg.pack(self.mav, force_mavlink1=self.opt.mavlink1)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.port.write(buf)
        self.sent_count[msg.get_type()] = self.sent_count.get(msg.get_type(), 0) + 1

    def _stream(self, now: float) -> None:
        for name, hz in self._rates().items():
            if hz <= 0 or now < self._due[name]:
                continue
            self._due[name] = max(self._due[name] + 1.0 / hz, now - 1.0 / hz)
            try:
                self._send(self._stream_message(name, now))
            except (struct.error, ValueError, OverflowError) as exc:
                # a value the message cannot carry (a wild trajectory): skip this one message
                self.skipped_messages += 1
                if name not in self._skip_logged:
                    self._skip_logged.add(name)
                    log.warning("%s not sent (%s); skipping such messages", name, exc)

    def _stream_message(self, name: str, now: float) -> object:
        """The stream message `name` at `now`; every stamp is on the boot clock, like a real
        autopilot's (TIMESYNC's ts1 included)."""
        uptime = now - self.boot_time
        boot_ms = int(uptime * 1000)
        if name == "HEARTBEAT":
            status = (mavlink2.MAV_STATE_STANDBY if now >= self.ekf_ready_at
                      else mavlink2.MAV_STATE_BOOT)
            return self.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR,
                                             AUTOPILOT_TYPE[self.opt.flavour], 0, 0, status)
        if name == "TIMESYNC":
            return self.mav.timesync_encode(0, round(uptime * 1e9))
        if name == "SYSTEM_TIME":
            return self.mav.system_time_encode(int(time.time() * 1e6), boot_ms)
        return sensor_message(self.mav, name, uptime, boot_ms, self.vehicle)

    def _receive(self, data: bytes, now: float) -> None:
        for msg in self.mav.parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                self.bad_frames += 1
                continue
            self.received.append(Received(now, msg))
            self._handle(msg, now)

    def _handle(self, msg: object, now: float) -> None:
        kind = msg.get_type()
        if kind == "TIMESYNC" and msg.tc1 != 0:
            self.timesync_rtts.append(now - self.boot_time - msg.ts1 / 1e9)
        elif kind == "SET_GPS_GLOBAL_ORIGIN":
            self._set_origin(now, "message", msg.latitude, msg.longitude, msg.altitude)
        elif kind in ("COMMAND_INT", "COMMAND_LONG"):
            self._command(msg, now)
        elif kind == "PARAM_REQUEST_READ":
            names = list(self.params)
            name = (msg.param_id if msg.param_index < 0 or msg.param_index >= len(names)
                    else names[msg.param_index])
            if name in self.params:
                self._send_param(name)
        elif kind == "PARAM_REQUEST_LIST":
            for name in self.params:
                self._send_param(name)

    def _command(self, msg: object, now: float) -> None:
        result = mavlink2.MAV_RESULT_UNSUPPORTED
        if msg.command == MAV_CMD_DO_SET_GLOBAL_ORIGIN and self.opt.supports_origin_command:
            if msg.get_type() == "COMMAND_INT":
                lat, lon, alt_m = msg.x, msg.y, msg.z
            else:
                lat, lon, alt_m = int(msg.param5 * 1e7), int(msg.param6 * 1e7), msg.param7
            ok = self._set_origin(now, "command", lat, lon, round(alt_m * 1000))
            result = mavlink2.MAV_RESULT_ACCEPTED if ok else mavlink2.MAV_RESULT_FAILED
        elif msg.command == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            result = mavlink2.MAV_RESULT_FAILED
            if int(msg.param1) == mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN and self.origin:
                self._send(self.mav.gps_global_origin_encode(*self.origin))
                result = mavlink2.MAV_RESULT_ACCEPTED
        self._send(self.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(),
                                               msg.get_srcComponent()))

    def _set_origin(self, now: float, kind: str, lat: int, lon: int, alt_mm: int) -> bool:
        """ArduPilot: only once, only when the EKF is ready; PX4: whenever asked."""
        refuse = self.opt.flavour == "ardupilot" and (self.origin is not None
                                                       or now < self.ekf_ready_at)
        self.origin_attempts.append((now, kind, not refuse))
        if refuse:
            return False
        self.origin = (lat, lon, alt_mm)
        self._send(self.mav.gps_global_origin_encode(lat, lon, alt_mm))
        return True

    def _send_param(self, name: str) -> None:
        value, param_type = self.params[name]
        self._send(self.mav.param_value_encode(
            name.encode(), wire_value(self.opt.flavour, value, param_type), param_type,
            len(self.params), list(self.params).index(name)))
