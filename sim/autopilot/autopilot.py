"""The time-stepped core of a simulated autopilot, shared by the ArduPilot and PX4 models: its
parameters, boot and reboot, the stream schedule on the companion's port, MAVLink parameter and
time-sync protocol, the EKF origin, the IMU-rate step of its estimator, and the record.

It runs on whatever clock it is given: `receive(msg, now)` for each message from the companion,
`step(now)` as often as possible; what it sends collects in `outbox` (pymavlink message
objects). SimAutopilot drives it on CLOCK_MONOTONIC over a real port; tests may drive it on a
virtual clock. The firmware specifics live in copter.py and px4.py.
"""

from __future__ import annotations

import logging
import struct
from abc import ABC, abstractmethod

from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot.dynamics import FlyingVehicle
from sim.autopilot.options import SimOptions
from sim.autopilot.param_store import ParamStore
from sim.autopilot.params import ParamSpec
from sim.autopilot.records import AutopilotRecord, Event, EventKind, Severity, StatusText
from sim.autopilot.sensing import Reading, Sensing
from sim.autopilot.streams import Schedule, interval_from_request, message_name
from sim.autopilot.vehicle import SENSOR_MESSAGES, sensor_message

log = logging.getLogger("sdvl.sim.autopilot")
MAV_CMD_DO_SET_GLOBAL_ORIGIN = 611  # common.xml (2025), not yet in pymavlink's dialect
IMU_DT = 0.02  # the stand-ins' prediction step: smooth flights need no more (EKF3 runs faster)
MAX_CATCH_UP_S = 0.1
STATUSTEXT_LEN = 50


class AutopilotModel(ABC):
    """Base of ArduCopterModel and Px4Model; subclasses fill in the firmware's rules."""

    autopilot_type = mavlink2.MAV_AUTOPILOT_GENERIC
    dialect = mavlink2  # ArduPilot sends ardupilotmega messages too (EKF_STATUS_REPORT)

    def __init__(self, options: SimOptions, vehicle: object, now: float) -> None:
        self.opt = options
        self.vehicle = vehicle
        self.mav = self.dialect.MAVLink(None, srcSystem=options.system_id, srcComponent=1)
        self.record = AutopilotRecord()
        self.outbox: list = []
        hardware = {} if options.dynamics is None else options.dynamics.hardware_params()
        stored = {**hardware, **options.stored_params()}
        self.params = ParamStore(self.param_specs(stored), stored)
        self.sensing = Sensing(options.imu_noise, options.seed)
        self.origin: tuple[int, int, int] | None = None
        self.origin_attempts: list[tuple[float, str, bool]] = []  # (t, kind, accepted)
        self.timesync_rtts: list[float] = []
        self.skipped_messages = 0
        self._skip_logged: set[str] = set()
        self._down_until: float | None = None
        self._text_id = 0
        self.boot(now)

    # --- firmware hooks (subclasses) -------------------------------------------------------

    @abstractmethod
    def param_specs(self, stored: dict[str, float]) -> dict[str, ParamSpec]:
        """The firmware's parameter table given the stored values."""

    @abstractmethod
    def on_boot(self, now: float) -> None:
        """Set up the firmware's parts (estimator, channel, mode) at boot."""

    @abstractmethod
    def port_active(self) -> bool:
        """Whether the firmware runs MAVLink on the companion's port (as booted)."""

    @abstractmethod
    def default_streams(self) -> dict[str, float]:
        """Message -> Hz streamed on the companion's port after boot (by parameters)."""

    @abstractmethod
    def estimator_step(self, now: float, reading: Reading, dt: float) -> None:
        """One IMU-rate step of the firmware's estimator."""

    @abstractmethod
    def firmware_message(self, name: str, now: float) -> object | None:
        """A stream message only the firmware can make (HEARTBEAT, estimator outputs)."""

    @abstractmethod
    def handle_firmware(self, msg: object, now: float) -> None:
        """Vision messages, SET_MODE and everything else firmware-specific."""

    @abstractmethod
    def command(self, msg: object, now: float) -> int:
        """MAV_RESULT of a COMMAND_LONG/COMMAND_INT the shared code does not handle."""

    @abstractmethod
    def known_message(self, name: str) -> bool:
        """Whether SET_MESSAGE_INTERVAL/REQUEST_MESSAGE know the message."""

    @abstractmethod
    def default_interval(self, name: str) -> float:
        """The interval SET_MESSAGE_INTERVAL 0 restores (0: not sent)."""

    @abstractmethod
    def set_param_from(self, name: str, msg: object) -> None:
        """Store a PARAM_SET's value by the firmware's rule."""

    @abstractmethod
    def timesync_reply(self, msg: object, now: float) -> None:
        """A TIMESYNC with tc1 set: a reply to one of our requests, or not."""

    @abstractmethod
    def arm(self, now: float, checks: bool = True) -> int:
        """Arm with (or without) the firmware's checks; the MAV_RESULT."""

    @abstractmethod
    def set_mode_named(self, name: str, now: float) -> bool:
        """Switch to a flight mode by its name; False when refused or unknown."""

    def wire(self, value: float, kind: int) -> float:
        """The float PARAM_VALUE carries for a value of type `kind`."""
        return float(value)

    def accept_origin(self, now: float) -> bool:
        """Whether the firmware takes an EKF origin now."""
        return True

    def sends_mavlink1(self) -> bool:
        """Whether the port is set to frame what the autopilot sends as MAVLink 1."""
        return False

    # --- boot, clock, output ---------------------------------------------------------------

    def boot(self, now: float) -> None:
        """Power on: parameters as stored, no origin, disarmed, streams from parameters."""
        self.boot_time = now
        self.params.boot(self.param_specs(self.params.saved))
        self.origin = None
        self.armed = False
        self._last_step = now
        self.sensing.baro_ground = None  # the barometer calibrates again where it boots
        self.schedule = Schedule()
        rates = self.default_streams()
        if self.opt.streams is not None:  # requested streams replace the parameters' own
            rates = {**{k: v for k, v in rates.items() if k in ("HEARTBEAT", "TIMESYNC")},
                     **self.opt.streams}
        for name, hz in rates.items():
            self.schedule.set(name, 1.0 / hz if hz > 0 else 0.0)
        self.on_boot(now)
        self.record.events.append(Event(now, EventKind.BOOT))

    def schedule_reboot(self, now: float, downtime_s: float) -> None:
        """Go silent for downtime_s, then boot again."""
        self._down_until = now + downtime_s

    @property
    def down(self) -> bool:
        return self._down_until is not None

    def uptime(self, now: float) -> float:
        return now - self.boot_time

    def send(self, msg: object) -> None:
        if self.port_active():
            self.outbox.append(msg)

    def say(self, severity: Severity, text: str, now: float | None = None) -> None:
        """STATUSTEXT (recorded even when the port is not sending)."""
        t = self._last_step if now is None else now
        self.record.statustexts.append(StatusText(t, severity, text))
        if len(text) <= STATUSTEXT_LEN:
            self.send(self.mav.statustext_encode(int(severity), text.encode()))
            return
        self._text_id = self._text_id % 255 + 1  # MAVLink 2 chunks share a non-zero id
        for seq, start in enumerate(range(0, len(text), STATUSTEXT_LEN)):
            self.send(self.mav.statustext_encode(
                int(severity), text[start:start + STATUSTEXT_LEN].encode(), self._text_id, seq))

    def take_outbox(self) -> list:
        out, self.outbox = self.outbox, []
        return out

    # --- the step --------------------------------------------------------------------------

    def step(self, now: float) -> None:
        """Advance to `now`: estimator at 50 Hz, then the streams that are due."""
        if self._down_until is not None:
            if now < self._down_until:
                return
            self._down_until = None
            self.boot(now)
        behind = now - self._last_step
        if behind > MAX_CATCH_UP_S and not self.flies:
            self._predict(now, behind - IMU_DT)  # a starved thread: one long step, not a backlog
        while now - self._last_step >= IMU_DT:
            self._predict(self._last_step + IMU_DT, IMU_DT)
        if self.flies:
            self.fly_ahead(now - self._last_step)
        for name in self.schedule.due(now):
            self._send_stream(name, now)

    @property
    def flies(self) -> bool:
        """Whether the vehicle flies on this model's controllers (SimOptions.dynamics)."""
        return isinstance(self.vehicle, FlyingVehicle)

    def _predict(self, t: float, dt: float) -> None:
        self._last_step = t
        if self.flies:
            reading = self.fly(dt)
        else:
            reading = self.sensing.read(self.vehicle, self.uptime(t), dt)
        self.estimator_step(t, reading, dt)

    def fly_ahead(self, elapsed: float) -> None:
        """Run the fast loops due `elapsed` s into the estimator's next step (firmwares whose
        vehicle can fly)."""
        raise NotImplementedError(f"{type(self).__name__} has no flight controllers")

    def fly(self, dt: float) -> Reading:
        """Run the firmware's fast loop (sensors, attitude control, motors, physics) for dt and
        read its sensors for the estimator (firmwares whose vehicle can fly)."""
        raise NotImplementedError(f"{type(self).__name__} has no flight controllers")

    def _send_stream(self, name: str, now: float) -> None:
        try:
            msg = self.stream_message(name, now)
        except (struct.error, ValueError, OverflowError) as exc:
            self.skip(name, exc)
            return
        if msg is not None:
            self.send(msg)

    def skip(self, name: str, exc: Exception) -> None:
        """A message with a value it cannot carry (a wild trajectory) is not sent; logged once
        per kind."""
        self.skipped_messages += 1
        if name not in self._skip_logged:
            self._skip_logged.add(name)
            log.warning("%s not sent (%s); skipping such messages", name, exc)

    def frame(self, msg: object, mavlink1: bool = False) -> bytes | None:
        """The message's bytes as the port sends them; None (and skipped) if it cannot be
        packed."""
        try:
            buf = msg.pack(self.mav, force_mavlink1=mavlink1 or self.sends_mavlink1())
        except (struct.error, ValueError, OverflowError) as exc:
            self.skip(msg.get_type(), exc)
            return None
        self.mav.seq = (self.mav.seq + 1) % 256
        return buf

    def stream_message(self, name: str, now: float) -> object | None:
        """The message `name` now; every stamp on the boot clock (TIMESYNC's ts1 too)."""
        uptime = self.uptime(now)
        if name in self.opt.absent:  # no such sensor fitted: asking streams nothing
            return None
        if name in SENSOR_MESSAGES:
            return sensor_message(self.mav, name, uptime, int(uptime * 1000), self.vehicle)
        if name == "SYSTEM_TIME":
            return self.mav.system_time_encode(int(now * 1e6), int(uptime * 1000))
        if name == "TIMESYNC":
            return self.timesync_request(now)
        return self.firmware_message(name, now)

    def timesync_request(self, now: float) -> object:
        return self.mav.timesync_encode(0, round(self.uptime(now) * 1e9))

    # --- receiving -------------------------------------------------------------------------

    def receive(self, msg: object, now: float) -> None:
        """Handle one message from the companion."""
        if self.down or not self.port_active():
            return
        kind = msg.get_type()
        if kind == "TIMESYNC":
            self._timesync(msg, now)
        elif kind == "SET_GPS_GLOBAL_ORIGIN":
            self.set_origin(now, "message", msg.latitude, msg.longitude, msg.altitude)
        elif kind in ("COMMAND_INT", "COMMAND_LONG"):
            self._command(msg, now)
        elif kind in ("PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "PARAM_SET"):
            self._param_message(msg)
        else:
            self.handle_firmware(msg, now)

    def _timesync(self, msg: object, now: float) -> None:
        """Answer a request (tc1 = 0) with our time of receipt; a reply to ours gives an RTT."""
        if msg.tc1 == 0:
            self.send(self.mav.timesync_encode(round(self.uptime(now) * 1e9), msg.ts1))
        else:
            self.timesync_reply(msg, now)

    def _command(self, msg: object, now: float) -> None:
        shared = {mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
                  mavlink2.MAV_CMD_REQUEST_MESSAGE: self._request_message,
                  MAV_CMD_DO_SET_GLOBAL_ORIGIN: self._origin_command,
                  mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._reboot_command}
        handler = shared.get(msg.command)
        result = handler(msg, now) if handler else self.command(msg, now)
        self.ack(msg, result)
        if msg.command == mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and \
                result == mavlink2.MAV_RESULT_ACCEPTED:
            self.schedule_reboot(now, self.opt.reboot_downtime_s)

    def ack(self, msg: object, result: int, command: int | None = None) -> None:
        self.send(self.mav.command_ack_encode(msg.command if command is None else command,
                                              result, 0, 0, msg.get_srcSystem(),
                                              msg.get_srcComponent()))

    def _set_message_interval(self, msg: object, now: float) -> int:
        name = message_name(int(msg.param1))
        if name is None or not self.known_message(name) or (name == "HEARTBEAT" and \
                self.autopilot_type == mavlink2.MAV_AUTOPILOT_PX4):
            return mavlink2.MAV_RESULT_FAILED
        self.schedule.set(name, interval_from_request(msg.param2, self.default_interval(name)))
        return mavlink2.MAV_RESULT_ACCEPTED

    def _request_message(self, msg: object, now: float) -> int:
        name = message_name(int(msg.param1))
        if name is None or not self.known_message(name):
            return mavlink2.MAV_RESULT_FAILED
        if name == "GPS_GLOBAL_ORIGIN":
            if self.origin is not None:
                self.send(self.mav.gps_global_origin_encode(*self.origin))
        else:
            self._send_stream(name, now)
        return mavlink2.MAV_RESULT_ACCEPTED

    def _reboot_command(self, msg: object, now: float) -> int:
        if self.armed:
            return mavlink2.MAV_RESULT_FAILED
        if int(msg.param1) != 1:
            return mavlink2.MAV_RESULT_UNSUPPORTED
        return mavlink2.MAV_RESULT_ACCEPTED

    # --- origin ----------------------------------------------------------------------------

    def _origin_command(self, msg: object, now: float) -> int:
        if not self.opt.supports_origin_command:
            return mavlink2.MAV_RESULT_UNSUPPORTED
        if msg.get_type() == "COMMAND_INT":
            lat, lon, alt_m = msg.x, msg.y, msg.z
        else:
            lat, lon, alt_m = int(msg.param5 * 1e7), int(msg.param6 * 1e7), msg.param7
        if lat == 0 and lon == 0:
            return mavlink2.MAV_RESULT_DENIED
        ok = self.set_origin(now, "command", lat, lon, round(alt_m * 1000))
        return mavlink2.MAV_RESULT_ACCEPTED if ok else mavlink2.MAV_RESULT_FAILED

    def set_origin(self, now: float, kind: str, lat: int, lon: int, alt_mm: int) -> bool:
        """Set the EKF origin if the firmware takes it; confirmed with GPS_GLOBAL_ORIGIN."""
        accept = self.accept_origin(now)
        self.origin_attempts.append((now, kind, accept))
        if not accept:
            return False
        self.origin = (lat, lon, alt_mm)
        self.send(self.mav.gps_global_origin_encode(lat, lon, alt_mm))
        return True

    # --- parameters ------------------------------------------------------------------------

    def _param_message(self, msg: object) -> None:
        kind = msg.get_type()
        names = self.params.names()
        if kind == "PARAM_REQUEST_LIST":
            for index, name in enumerate(names):
                self.send_param(name, index)
        elif kind == "PARAM_REQUEST_READ":
            by_index = 0 <= msg.param_index < len(names)
            name = names[msg.param_index] if by_index else msg.param_id
            if name in self.params:
                self.send_param(name, msg.param_index if by_index else self.read_index(name))
        elif msg.param_id in self.params:
            self.set_param_from(msg.param_id, msg)
            self.send_param(msg.param_id, self.read_index(msg.param_id))

    def read_index(self, name: str) -> int:
        """The param_index a reply by name carries."""
        return self.params.names().index(name)

    def send_param(self, name: str, index: int) -> None:
        kind = self.params.specs[name].kind
        self.send(self.mav.param_value_encode(
            name.encode(), self.wire(self.params.stored(name), kind), kind,
            len(self.params.names()), index))
