"""The autopilot's end of a closed-loop flight: the simulated ArduCopter flying on its own
controllers (sim/autopilot, SimOptions.dynamics) over the world's ground, set up as after
`sdvl check-autopilot --apply`, with a ground station flying the mission on the same link (as
mavlink-router joins a GCS to the companion's port) and the truth kept for the report.

Whoever drives it (the virtual-clock loop, the real-time process) hands it the companion's bytes
(`from_companion`) and calls `step(now)`, which returns the bytes for the companion: everything
the autopilot sent but the streams of the sensors left out (`without`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from scipy.spatial.transform import Rotation

from sim.autopilot.barometer import BaroSpec
from sim.autopilot.dynamics import Dynamics
from sim.autopilot.imu import ImuSpec
from sim.autopilot.options import configured_options
from sim.autopilot.simulator import make_model
from sim.flight.flight_run import Timing
from sim.flight.gcs import GroundStation
from sim.flight.mission import Mission
from sim.flight.runner import MissionRunner
from sim.flight.world import FlightWorld
from sim.replay.flight import SENSOR_STREAMS
from sim.trajectory import Trajectory

TRUTH_PERIOD_S = 0.02
MARGIN_S = 30.0  # beyond the mission's own time limits, the flight is cut off


class DelayLine:
    """Bytes delivered in order a fixed delay after they were put in."""

    def __init__(self, delay_s: float, deliver: Callable[[bytes], None]):
        self.delay_s, self.deliver = delay_s, deliver
        self._queue: deque[tuple[float, bytes]] = deque()

    def put(self, now: float, data: bytes) -> None:
        self._queue.append((now + self.delay_s, data))

    def next_due(self) -> float:
        """When the next bytes arrive (inf: none on the way)."""
        return self._queue[0][0] if self._queue else np.inf

    def run(self, now: float) -> None:
        while self._queue and self._queue[0][0] <= now + 1e-12:
            self.deliver(self._queue.popleft()[1])


class AutopilotSide:
    """The model, the ground station and the mission runner; times are the model's clock
    (seconds since it booted at `now`)."""

    def __init__(self, mission: Mission, world: FlightWorld, seed: int, timing: Timing,
                 without: tuple[str, ...] = (), now: float = 0.0,
                 on_step: Callable[[str], None] | None = None, baro: BaroSpec | None = None,
                 imu: ImuSpec | None = None):
        self.now = now
        options = configured_options(by_parameter=True, seed=seed, dynamics=Dynamics(
            terrain=world.range, baro=baro or BaroSpec(), imu=imu or ImuSpec()))
        self.model = make_model(options, None, now)
        self.hidden = {name for kind in without for name in SENSOR_STREAMS[kind]}
        self.gcs = GroundStation(lambda data: self._from_gcs.put(self.now, data))
        self.runner = MissionRunner(mission, self.gcs, on_step)
        self._from_gcs = DelayLine(timing.gcs_link_s, self._receiver())
        self._to_gcs = DelayLine(timing.gcs_link_s, lambda data: self.gcs.feed(data, self.now))
        self._from_companion = self._receiver()
        self.limit = now + MARGIN_S + sum(s.timeout_s or float(s.value) for s in mission.steps)
        self.truth: list[tuple[float, np.ndarray]] = []
        self.compass: list[float] = []

    @property
    def done(self) -> bool:
        """The mission has ended, or run out of time."""
        return self.runner.done or self.now >= self.limit

    @property
    def T_ned_body(self) -> np.ndarray:
        return self.model.vehicle.T_ned_body

    def _receiver(self) -> Callable[[bytes], None]:
        parser = ardupilotmega.MAVLink(None)
        parser.robust_parsing = True

        def deliver(data: bytes) -> None:
            for msg in parser.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA":
                    self.model.receive(msg, self.now)
        return deliver

    def from_companion(self, data: bytes, now: float) -> None:
        """The companion's bytes arrive (the router passes them on to the ground station)."""
        self.now = now
        self._from_companion(data)
        self._to_gcs.put(now, data)

    def step(self, now: float) -> list[bytes]:
        """Advance to `now`; the bytes the autopilot sent the companion meanwhile."""
        self.now = now
        self.model.step(now)
        self._from_gcs.run(now)
        self._to_gcs.run(now)
        out = []
        for msg in self.model.take_outbox():
            data = self.model.frame(msg)
            if data is None:
                continue
            self._to_gcs.put(now, data)
            if msg.get_type() not in self.hidden:
                out.append(data)
            if msg.get_type() == "ATTITUDE":
                self._compass_error(msg.yaw)
        self.runner.tick(now)
        if not self.truth or now - self.truth[-1][0] >= TRUTH_PERIOD_S - 1e-9:
            self.truth.append((now, self.T_ned_body))
        return out

    def _compass_error(self, yaw: float) -> None:
        """The heading the autopilot reports against the truth (its compass error), degrees."""
        true_yaw = Rotation.from_matrix(self.T_ned_body[:3, :3]).as_euler("ZYX")[0]
        self.compass.append(float(np.degrees(np.angle(np.exp(1j * (yaw - true_yaw))))))

    def truth_trajectory(self, since: float = 0.0) -> Trajectory:
        """The body's true poses (NED), times less `since`."""
        t = np.array([s[0] for s in self.truth]) - since
        return Trajectory.from_matrices(t, np.array([s[1] for s in self.truth]))

    def viso_delay_ms(self) -> float | None:
        params = self.model.params
        return params.get("VISO_DELAY_MS") if "VISO_DELAY_MS" in params else None
