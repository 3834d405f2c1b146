"""The closed loop on a virtual clock (`sdvl fly`, the default): deterministic, whatever the
machine's load.

Three MAVLink endpoints share the autopilot's link: the simulated ArduCopter with a ground
station flying the mission (autopilot_side.py) and our service's parts (companion.py). Every
message crosses as bytes after the link's latency. Each camera frame is rendered where the
vehicle truly is at that instant (world.py), tracked, and its estimate sent `capture_to_send_s`
later. Timing model (flight_run.Timing):

    frame k at t_k = k / fps; our capture stamp t_k on our clock (its own offset)
    tracker + fusion: the estimate leaves at t_k + capture_to_send_s
    link: ODOMETRY reaches the autopilot link_s later; its messages reach us link_s after sending
    ground station <-> autopilot: gcs_link_s each way
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from daemon.config import Config, OriginConfig, replace
from daemon.run_command import tracker_factory
from sim.autopilot.barometer import BaroSpec
from sim.autopilot.imu import ImuSpec
from sim.flight.autopilot_side import AutopilotSide, DelayLine
from sim.flight.companion import LockstepCompanion, Tracked
from sim.flight.flight_run import FlightRun, Timing
from sim.flight.frame_drops import FrameDrops
from sim.flight.mission import Mission
from sim.flight.world import FlightWorld
from sim.replay.autopilot_process import VisionMessage
from sim.replay.flight import drone_config
from sim.replay.lockstep import lockstep_config

# ArduPilot SITL's default site, CMAC (Tools/autotest/locations.txt): latitude, longitude, m
SITE = (-35.363261, 149.165230, 584.0)


def flight_config(config: Config, world: FlightWorld) -> Config:
    """The service's config for the world's drone: its camera mounting, the fusion on, and the
    EKF origin at the take-off site (the README's step for a vehicle without GPS) unless the
    config sets its own."""
    config = replace(drone_config(config, world.drone()), fusion={"enabled": True})
    if config.origin != OriginConfig():
        return config
    return replace(config, origin={"enabled": True, "latitude_deg": SITE[0],
                                   "longitude_deg": SITE[1], "altitude_m": SITE[2]})


class ClosedLoop:
    """One flight of `mission` (see the module doc); `run()` returns the FlightRun."""

    def __init__(self, mission: Mission, config: Config, seed: int = 0,
                 size: tuple[int, int] | None = None, without: tuple[str, ...] = (),
                 timing: Timing | None = None, make_tracker: Callable | None = None,
                 on_step: Callable[[str], None] | None = None, baro: BaroSpec | None = None,
                 imu: ImuSpec | None = None):
        self.mission, self.seed, self.without = mission, seed, without
        self.timing = tm = timing or Timing()
        self.world = FlightWorld.of_preset(mission.world, seed, size)
        self.config = lockstep_config(flight_config(config, self.world))
        self.now = 0.0
        self.autopilot = AutopilotSide(mission, self.world, seed, tm, without, self.now,
                                       on_step, baro, imu)
        self.to_autopilot = DelayLine(tm.link_s,
                                      lambda data: self.autopilot.from_companion(data, self.now))
        self.companion = LockstepCompanion(
            self.config, make_tracker or tracker_factory(self.config, self.world.camera),
            lambda data: self.to_autopilot.put(self.now, data),
            lambda: self.now + tm.our_clock_s)
        self.to_companion = DelayLine(tm.link_s, self.companion.feed)
        self.pending: deque[tuple[float, Future]] = deque()  # (due, the worker's Tracked)
        self.drops = FrameDrops(tm.drop_share, seed)

    def run(self) -> FlightRun:
        """Fly until the mission has ended (or its time limit). A worker thread renders and
        tracks each frame while this one flies on: the estimate is due only capture_to_send_s
        after the capture, and the worker takes the frames in order, so the flight is the same
        as one thread's (the kernels release the GIL)."""
        tm = self.timing
        frame = 0
        cpu0, wall0 = time.process_time(), time.perf_counter()
        try:
            with ThreadPoolExecutor(1, thread_name_prefix="camera") as camera:
                while not self.autopilot.done:
                    next_frame = (frame + 1) / tm.fps
                    self.now = min(self.now + tm.step_s, next_frame, self._next_event())
                    for data in self.autopilot.step(self.now):
                        self.to_companion.put(self.now, data)
                    self.to_autopilot.run(self.now)
                    self.to_companion.run(self.now)
                    self.companion.tick()
                    if self.now >= next_frame - 1e-9:
                        frame += 1
                        if not self.drops.drop():
                            self._capture(camera, frame)
                    while self.pending and self.pending[0][0] <= self.now + 1e-9:
                        self.companion.publish(self.pending.popleft()[1].result())
        finally:
            self.companion.close()
        return self._result(time.process_time() - cpu0, time.perf_counter() - wall0, frame)

    def _next_event(self) -> float:
        """The next estimate due or message arriving between us and the autopilot: the loop
        steps to it, so latencies are exactly the timing's."""
        due = self.pending[0][0] if self.pending else np.inf
        return min(due, self.to_autopilot.next_due(), self.to_companion.next_due())

    def _capture(self, camera: ThreadPoolExecutor, index: int) -> None:
        """Frame `index`, where the vehicle is now: rendered and tracked by the worker."""
        tm = self.timing
        pose = self.autopilot.T_ned_body.copy()
        t_capture = self.now + tm.our_clock_s
        orientation = self.companion.estimator.orientation(t_capture)
        self.pending.append((self.now + tm.capture_to_send_s, camera.submit(
            self._render_track, index, self.now, t_capture, pose, orientation)))

    def _render_track(self, index: int, t: float, t_capture: float, T_ned_body: np.ndarray,
                      orientation: object) -> Tracked:
        image, depth = self.world.frame(index, t, T_ned_body, self.config.camera.depth)
        return self.companion.track(index, t, t_capture, image, depth, orientation)

    def _result(self, cpu_s: float, wall_s: float, offered: int) -> FlightRun:
        ap = self.autopilot
        sent = [VisionMessage(m.kind, m.t_arrival + self.timing.link_s, m.fields)
                for m in self.companion.sent]
        return FlightRun(self.mission, self.seed, self.without, self.timing,
                         ap.truth_trajectory(), ap.runner.results, sent, self.companion.rows,
                         ap.model.record, ap.viso_delay_ms(), ap.compass, wall_s=wall_s,
                         cpu_s=cpu_s, offered=offered if self.drops.dropped else None)
