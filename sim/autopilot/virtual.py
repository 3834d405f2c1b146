"""A simulated autopilot on a virtual clock with a scripted companion, for tests (and scripts)
that must not wait in real time: messages go through MAVLink 2 framing both ways, so field
types and truncation are the wire's."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from sim.autopilot.autopilot import AutopilotModel
from sim.autopilot.options import SimOptions
from sim.autopilot.simulator import make_model

STEP_S = 0.005
COMPANION = (1, 197)  # system, component (MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY)


class VirtualLink:
    """`model` advanced by `advance`; `send` delivers a companion message at the current time;
    everything the autopilot sent is in `heard` as (time, message)."""

    def __init__(self, options: SimOptions, vehicle: object | None = None,
                 start: float = 1000.0) -> None:
        self.now = start
        self.model: AutopilotModel = make_model(options, vehicle, start)
        self.mav = mavlink2.MAVLink(None, srcSystem=COMPANION[0], srcComponent=COMPANION[1])
        self._out_parser = ardupilotmega.MAVLink(None)
        self._in_parser = ardupilotmega.MAVLink(None)
        self.heard: list[tuple[float, object]] = []

    def send(self, msg: object, sender: mavlink2.MAVLink | None = None) -> None:
        """Deliver `msg` from the companion, or from `sender` (e.g. a ground station's
        MAVLink with its own system id)."""
        mav = sender or self.mav
        data = msg.pack(mav)
        mav.seq = (mav.seq + 1) % 256
        for parsed in self._in_parser.parse_buffer(data) or []:
            self.model.receive(parsed, self.now)
        self._collect()

    def advance(self, seconds: float, every: float = 0.0,
                action: Callable[[float], None] | None = None) -> None:
        """Step the clock by `seconds`; `action(now)` runs every `every` seconds meanwhile."""
        end = self.now + seconds
        next_action = self.now
        while self.now < end - 1e-9:
            self.now = min(self.now + STEP_S, end)
            if action is not None and self.now >= next_action:
                next_action += every
                action(self.now)
            self.model.step(self.now)
            self._collect()

    def _collect(self) -> None:
        for msg in self.model.take_outbox():
            data = self.model.frame(msg)
            if data is not None:
                self.heard.extend((self.now, m) for m in self._out_parser.parse_buffer(data) or [])

    def of(self, name: str, since: float = -np.inf) -> list:
        return [m for t, m in self.heard if m.get_type() == name and t >= since]

    def texts(self) -> list[str]:
        """STATUSTEXTs heard, MAVLink 2 chunks (same non-zero id) joined."""
        out: list[str] = []
        last_id = 0
        for msg in self.of("STATUSTEXT"):
            if msg.id and msg.id == last_id and msg.chunk_seq > 0:
                out[-1] += msg.text
            else:
                out.append(msg.text)
            last_id = msg.id
        return out

    def command(self, command: int, *params: float) -> int | None:
        """COMMAND_LONG to the autopilot; the result of its COMMAND_ACK (None if none)."""
        args = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        since = self.now
        self.send(self.mav.command_long_encode(1, 1, command, 0, *args))
        acks = [m for m in self.of("COMMAND_ACK", since) if m.command == command]
        return acks[-1].result if acks else None

    def odometry(self, position: np.ndarray, attitude: Rotation, velocity_body: np.ndarray,
                 reset_counter: int = 0, position_var: float = 0.01, quality: int = 100,
                 stamp_s: float | None = None) -> None:
        """An ODOMETRY as a vision companion sends it (LOCAL_FRD / BODY_FRD, VIO)."""
        x, y, z, w = attitude.as_quat()
        cov = [np.nan] * 21
        cov[0] = cov[6] = cov[11] = position_var
        cov[15] = cov[18] = cov[20] = 1e-4
        stamp = self.now if stamp_s is None else stamp_s
        self.send(self.mav.odometry_encode(
            int(stamp * 1e6), 20, 12, *position, [w, x, y, z], *velocity_body, 0, 0, 0, cov,
            [np.nan] * 21, reset_counter, 3, quality))
