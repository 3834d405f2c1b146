"""The closed loop on a virtual clock (`sdvl fly`, the default): deterministic, whatever the
machine's load.

Three MAVLink endpoints share the autopilot's link, as with mavlink-router on the companion:
the simulated ArduCopter (sim/autopilot), our service's parts (companion.py) and a ground
station flying the mission (gcs.py, runner.py). Every message crosses as bytes after the link's
latency. Each camera frame is rendered where the vehicle truly is at that instant (world.py),
tracked, and its estimate sent `capture_to_send_s` later. Timing model (Timing):

    frame k at t_k = k / fps; our capture stamp t_k on our clock (its own offset)
    tracker + fusion: the estimate leaves at t_k + capture_to_send_s
    link: ODOMETRY reaches the autopilot link_s later; its messages reach us link_s after sending
    ground station <-> autopilot: gcs_link_s each way
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from scipy.spatial.transform import Rotation

from daemon.config import Config, replace
from daemon.run_command import tracker_factory
from sim.autopilot.dynamics import Dynamics
from sim.autopilot.options import configured_options
from sim.autopilot.records import AutopilotRecord
from sim.autopilot.simulator import make_model
from sim.flight.companion import LockstepCompanion, Tracked
from sim.flight.gcs import GroundStation
from sim.flight.mission import Mission
from sim.flight.runner import MissionRunner, StepResult
from sim.flight.world import FlightWorld
from sim.replay.autopilot_process import VisionMessage
from sim.replay.flight import SENSOR_STREAMS, drone_config
from sim.replay.lockstep import lockstep_config
from sim.trajectory import Trajectory

TRUTH_PERIOD_S = 0.02
MARGIN_S = 30.0  # beyond the mission's own time limits, the run is cut off


@dataclass(frozen=True)
class Timing:
    """The loop's clock and latencies, seconds."""

    fps: float = 30.0
    capture_to_send_s: float = 0.035  # autopilot-interface.md (e) 7: 31-38 ms measured
    link_s: float = 0.003  # an ODOMETRY frame (257 bytes) at 921600 baud
    gcs_link_s: float = 0.02  # a telemetry radio, one way
    step_s: float = 0.0025  # ArduCopter's 400 Hz main loop
    our_clock_s: float = 5000.0  # our monotonic clock when the autopilot boots


@dataclass
class FlightRun:
    """Everything the report scores, times in seconds since the autopilot booted (our clock is
    that plus `timing.our_clock_s`)."""

    mission: Mission
    seed: int
    without: tuple[str, ...]
    timing: Timing
    truth: Trajectory  # body FRD in NED, the world's frame
    steps: list[StepResult]
    sent: list[VisionMessage]  # t_arrival: when it reached the autopilot (our clock)
    rows: list[dict]  # one per tracked frame, as the replay's recorder
    record: AutopilotRecord
    viso_delay_ms: float | None
    compass_errors_deg: list[float] = field(default_factory=list)
    realtime: bool = False
    wall_s: float = 0.0
    cpu_s: float = 0.0


class DelayLine:
    """Bytes delivered in order a fixed delay after they were put in."""

    def __init__(self, delay_s: float, deliver: Callable[[bytes], None]):
        self.delay_s, self.deliver = delay_s, deliver
        self._queue: deque[tuple[float, bytes]] = deque()

    def put(self, now: float, data: bytes) -> None:
        self._queue.append((now + self.delay_s, data))

    def run(self, now: float) -> None:
        while self._queue and self._queue[0][0] <= now + 1e-12:
            self.deliver(self._queue.popleft()[1])



class ClosedLoop:
    """One flight of `mission` (see the module doc); `run()` returns the FlightRun."""

    def __init__(self, mission: Mission, config: Config, seed: int = 0,
                 size: tuple[int, int] | None = None, without: tuple[str, ...] = (),
                 timing: Timing | None = None, make_tracker: Callable | None = None):
        self.mission, self.seed, self.without = mission, seed, without
        self.timing = timing or Timing()
        self.world = FlightWorld.of_preset(mission.world, seed, size)
        self.config = lockstep_config(replace(drone_config(config, self.world.drone()),
                                              fusion={"enabled": True}))
        self.now = 0.0
        self.model = make_model(configured_options(by_parameter=True, seed=seed,
                                                   dynamics=Dynamics(terrain=self.world.range)),
                                None, self.now)
        self.hidden = {name for kind in without for name in SENSOR_STREAMS[kind]}
        tm = self.timing
        self._to_autopilot = {"companion": self._receiver(), "gcs": self._receiver()}
        self.lines = {
            "companion>autopilot": DelayLine(tm.link_s, self._to_autopilot["companion"]),
            "gcs>autopilot": DelayLine(tm.gcs_link_s, self._to_autopilot["gcs"]),
            "autopilot>companion": DelayLine(tm.link_s, self._companion_feed),
            "autopilot>gcs": DelayLine(tm.gcs_link_s, self._gcs_feed),
            "companion>gcs": DelayLine(tm.link_s + tm.gcs_link_s, self._gcs_feed)}
        make_tracker = make_tracker or tracker_factory(self.config, self.world.camera)
        self.companion = LockstepCompanion(self.config, make_tracker, self._companion_write,
                                           lambda: self.now + tm.our_clock_s)
        self.gcs = GroundStation(lambda data: self.lines["gcs>autopilot"].put(self.now, data))
        self.runner = MissionRunner(mission, self.gcs)
        self.pending: deque[Tracked] = deque()
        self.truth: list[tuple[float, np.ndarray]] = []
        self.compass: list[float] = []

    # --- wiring ------------------------------------------------------------------------------

    def _receiver(self) -> Callable[[bytes], None]:
        parser = ardupilotmega.MAVLink(None)
        parser.robust_parsing = True

        def deliver(data: bytes) -> None:
            for msg in parser.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA":
                    self.model.receive(msg, self.now)
        return deliver

    def _companion_write(self, data: bytes) -> None:
        self.lines["companion>autopilot"].put(self.now, data)
        self.lines["companion>gcs"].put(self.now, data)

    def _companion_feed(self, data: bytes) -> None:
        self.companion.feed(data)

    def _gcs_feed(self, data: bytes) -> None:
        self.gcs.feed(data, self.now)

    def _autopilot_out(self) -> None:
        """The model's outbox onto the link: the ground station hears everything, we hear all
        but the streams of the sensors left out."""
        for msg in self.model.take_outbox():
            data = self.model.frame(msg)
            if data is None:
                continue
            self.lines["autopilot>gcs"].put(self.now, data)
            if msg.get_type() not in self.hidden:
                self.lines["autopilot>companion"].put(self.now, data)
            if msg.get_type() == "ATTITUDE":
                self._compass_error(msg.yaw)

    def _compass_error(self, yaw: float) -> None:
        """The heading the autopilot reports against the truth (its compass error), degrees."""
        true_yaw = Rotation.from_matrix(self.model.vehicle.T_ned_body[:3, :3]).as_euler(
            "ZYX")[0]
        self.compass.append(float(np.degrees(np.angle(np.exp(1j * (yaw - true_yaw))))))

    # --- the loop ----------------------------------------------------------------------------

    def time_limit(self) -> float:
        """The mission's steps' own limits added up, and a margin."""
        return MARGIN_S + sum(s.timeout_s or float(s.value) for s in self.mission.steps)

    def run(self) -> FlightRun:
        """Fly until the mission has ended (or its time limit)."""
        tm = self.timing
        frame, next_truth = 0, 0.0
        cpu0, wall0 = time.process_time(), time.perf_counter()
        limit = self.time_limit()
        try:
            while not self.runner.done and self.now < limit:
                next_frame = (frame + 1) / tm.fps
                self.now = min(self.now + tm.step_s, next_frame)
                self.model.step(self.now)
                for line in self.lines.values():
                    line.run(self.now)
                self._autopilot_out()
                self.companion.tick()
                self.runner.tick(self.now)
                if self.now >= next_frame - 1e-9:
                    frame += 1
                    self._capture(frame)
                while self.pending and self.pending[0].due <= self.now + tm.our_clock_s + 1e-9:
                    self.companion.publish(self.pending.popleft())
                if self.now >= next_truth:
                    next_truth += TRUTH_PERIOD_S
                    self.truth.append((self.now, self.model.vehicle.T_ned_body))
        finally:
            self.companion.close()
        return self._result(time.process_time() - cpu0, time.perf_counter() - wall0)

    def _capture(self, index: int) -> None:
        """Render frame `index` where the vehicle is now and track it."""
        image = self.world.image(index, self.now, self.model.vehicle.T_ned_body)
        self.pending.append(self.companion.track(index, self.now, image,
                                                 self.timing.capture_to_send_s,
                                                 time.perf_counter))

    def _result(self, cpu_s: float, wall_s: float) -> FlightRun:
        t = np.array([s[0] for s in self.truth])
        truth = Trajectory.from_matrices(t, np.array([s[1] for s in self.truth]))
        link = self.timing.link_s
        sent = [VisionMessage(m.kind, m.t_arrival + link, m.fields)
                for m in self.companion.sent]
        viso = self.model.params.get("VISO_DELAY_MS") if "VISO_DELAY_MS" in self.model.params \
            else None
        return FlightRun(self.mission, self.seed, self.without, self.timing, truth,
                         self.runner.results, sent, self.companion.rows, self.model.record,
                         viso, self.compass, wall_s=wall_s, cpu_s=cpu_s)
