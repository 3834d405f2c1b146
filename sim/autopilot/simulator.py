"""A simulated autopilot that talks MAVLink to the companion over UDP, TCP or a pty.

SimAutopilot runs an ArduCopter or PX4 model (copter.py, px4.py) in its own thread on
CLOCK_MONOTONIC: everything the companion sends is parsed, recorded with its arrival time and
handed to the model; the model's output is framed (MAVLink 2, or 1 on a port set to MAVLink 1)
and written to the port. What the model imitates, and where that is from:
sim/autopilot/BEHAVIOUR.md. A new SimAutopilot is a fresh firmware; `configured_options()` gives
one set up for vision.
"""

from __future__ import annotations

import contextlib
import select
import threading
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot.autopilot import AutopilotModel
from sim.autopilot.copter import ArduCopterModel
from sim.autopilot.dynamics import FlyingVehicle
from sim.autopilot.options import DEFAULT_STREAMS, SimOptions, configured_options
from sim.autopilot.ports import open_port
from sim.autopilot.px4 import Px4Model
from sim.autopilot.records import AutopilotRecord
from sim.autopilot.streams import VISION_MESSAGES
from sim.autopilot.vehicle import Vehicle

__all__ = ["DEFAULT_STREAMS", "Received", "SimAutopilot", "SimOptions", "configured_options",
           "make_model"]


@dataclass
class Received:
    """One message from the companion and when it arrived (monotonic seconds)."""

    t: float
    msg: object


def make_model(options: SimOptions, vehicle: object | None, now: float) -> AutopilotModel:
    """The firmware model for `options.flavour` ("ardupilot" or "px4") with its vehicle: the
    one given, else a flying one (`options.dynamics`, ArduCopter only) or the scripted one
    (`options.trajectory`, by default a slow hover)."""
    if options.dynamics is not None and options.flavour != "ardupilot":
        raise ValueError("SimOptions.dynamics: only the simulated ArduCopter flies (PX4's "
                         "controllers are not modelled); use flavour='ardupilot'")
    if vehicle is None:
        vehicle = (FlyingVehicle(options.dynamics) if options.dynamics is not None
                   else Vehicle(options.trajectory))
    model = {"ardupilot": ArduCopterModel, "px4": Px4Model}[options.flavour]
    return model(options, vehicle, now)


class SimAutopilot:
    """Start with `start()` (or as a context manager); the companion connects to `url`."""

    def __init__(self, options: SimOptions | None = None):
        self.opt = options or SimOptions()
        self.port = open_port(self.opt.port)
        self.url = self.port.url
        self.model = make_model(self.opt, None, time.monotonic())
        self.parser = ardupilotmega.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[Received] = []
        self.bad_frames = 0
        self.sent_count: dict[str, int] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-autopilot", daemon=True)
        self._silent_until = 0.0

    # --- control from tests and the replay --------------------------------------------------

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

    @property
    def vehicle(self) -> object:
        return self.model.vehicle

    @vehicle.setter
    def vehicle(self, vehicle: object) -> None:
        with self._lock:
            self.model.vehicle = vehicle

    def lose_link(self, seconds: float) -> None:
        """Neither send nor hear anything for `seconds` (a cable fault, radio fade)."""
        with self._lock:
            self._silent_until = time.monotonic() + seconds

    def reboot(self, downtime_s: float = 0.5) -> None:
        """Go silent, then boot again: parameters as stored, no origin, EKF restarting."""
        with self._lock:
            self.model.schedule_reboot(time.monotonic(), downtime_s)

    def inject(self, data: bytes) -> None:
        """Write raw bytes to the companion (garbage, truncated frames)."""
        with self._lock:
            self.port.write(data)

    def arm(self, force: bool = False) -> bool:
        """Arm as the pilot's transmitter or ground station would; False when refused (the
        reasons went out as STATUSTEXT and are in `record`)."""
        with self._lock:
            return self.model.arm(time.monotonic(), checks=not force) == \
                mavlink2.MAV_RESULT_ACCEPTED

    def set_mode(self, name: str) -> bool:
        """Switch flight mode by name (ArduCopter: STABILIZE, ALT_HOLD, GUIDED, LOITER, LAND;
        PX4: Manual, Altitude, Position, Hold, Land, ...); False when refused."""
        with self._lock:
            return self.model.set_mode_named(name, time.monotonic())

    @property
    def armed(self) -> bool:
        return self.model.armed

    @property
    def record(self) -> AutopilotRecord:
        """STATUSTEXTs, events and the estimate history (see records.py)."""
        return self.model.record

    @property
    def params(self) -> object:
        return self.model.params

    @property
    def origin(self) -> tuple[int, int, int] | None:
        return self.model.origin

    @property
    def origin_attempts(self) -> list[tuple[float, str, bool]]:
        return self.model.origin_attempts

    @property
    def boot_time(self) -> float:
        return self.model.boot_time

    @property
    def timesync_rtts(self) -> list[float]:
        return self.model.timesync_rtts

    @property
    def skipped_messages(self) -> int:
        return self.model.skipped_messages

    def messages(self, name: str, since: float = 0.0) -> list[Received]:
        """Received messages of one type, arrived at or after `since`."""
        with self._lock:
            return [r for r in self.received if r.msg.get_type() == name and r.t >= since]

    @property
    def vision(self) -> list[Received]:
        with self._lock:
            return [r for r in self.received if r.msg.get_type() in VISION_MESSAGES]

    # --- the thread -----------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError, ValueError):
                select.select([self.port], [], [], 0.002)
            data = self.port.read()
            now = time.monotonic()
            with self._lock:
                if now < self._silent_until:
                    continue
                if data:
                    self._receive(data, now)
                self.model.step(now)
                for msg in self.model.take_outbox():
                    self._send(msg)

    def _receive(self, data: bytes, now: float) -> None:
        for msg in self.parser.parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                self.bad_frames += 1
                continue
            self.received.append(Received(now, msg))
            self.model.receive(msg, now)

    def _send(self, msg: object) -> None:
        buf = self.model.frame(msg, self.opt.mavlink1)
        if buf is not None:
            self.port.write(buf)
            self.sent_count[msg.get_type()] = self.sent_count.get(msg.get_type(), 0) + 1
