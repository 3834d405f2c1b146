"""The simulated autopilot in its own process (a real one does not share the companion's GIL),
flying a vehicle trajectory in step with the frames the replay releases.

The replay's frame source publishes `clock = (t_capture - t_source, t_source)` of the newest
frame it released into shared memory; the vehicle's time is the sequence time `now - offset`,
held still at the start pose before the flight (the pre-flight on the ground, when the pilot
arms: pilot.py) and never ahead of the newest frame by more than `MAX_LEAD_S` (so an
as-fast-as-possible replay does not fly ahead of its frames).
"""

from __future__ import annotations

import math
import multiprocessing
import multiprocessing.connection
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sim.autopilot import SimAutopilot, SimOptions, configured_options
from sim.autopilot.records import AutopilotRecord
from sim.autopilot.vehicle import Vehicle, nearest_sample
from sim.datasets.layout import SensorSamples
from sim.replay.pilot import Pilot
from sim.sequence import ImuSamples
from sim.trajectory import Trajectory

# a fork would copy locks this process's other threads hold (numba compiling a kernel) and
# the child could wait on them forever; the fork server is a fresh single-threaded process
START_METHOD = "forkserver"

MAX_LEAD_S = 0.1
PAD_S = 1.0  # the trajectory is held this long at both ends, so its derivatives stay defined
PREFLIGHT_ERRORS_S = 2.0  # the pre-flight's attitude errs as the flight's does on average over this
PILOT_TICK_S = 0.05


@dataclass(frozen=True)
class VisionMessage:
    """One vision message the autopilot received: its type, arrival time (monotonic s) and
    fields (`msg.to_dict()`), picklable across the process boundary."""

    kind: str
    t_arrival: float
    fields: dict


def padded(trajectory: Trajectory) -> Trajectory:
    """The trajectory with its first and last pose held for PAD_S seconds."""
    t = np.concatenate([[trajectory.t[0] - PAD_S], trajectory.t, [trajectory.t[-1] + PAD_S]])
    pos = np.vstack([trajectory.positions[:1], trajectory.positions, trajectory.positions[-1:]])
    quat = np.vstack([trajectory.quaternions[:1], trajectory.quaternions,
                      trajectory.quaternions[-1:]])
    return Trajectory(t, pos, quat)


class ReplayVehicle:
    """A Vehicle whose time is the replay's sequence time instead of the autopilot's uptime;
    with `imu` (recorded body-FRD samples) the IMU readings are the recorded ones, with
    `sensors` (a synthetic flight's) the attitude, barometer and rangefinder too, noise and
    compass bias included."""

    def __init__(self, trajectory: Trajectory, clock: multiprocessing.Array,
                 imu: ImuSamples | None = None, sensors: SensorSamples | None = None,
                 imu_bias: tuple[np.ndarray, np.ndarray] | None = None):
        self.inner = Vehicle(padded(trajectory))
        self.t_first, self.t_last = float(trajectory.t[0]), float(trajectory.t[-1])
        self.clock = clock
        self.imu = imu
        self.sensors = sensors
        # the recorded attitude's mean error, which the pre-flight's attitude carries
        self.attitude_error = self._mean_attitude_error() if sensors is not None else None
        # the IMU's own (accel, gyro) bias at the flight's start, which the pre-flight's
        # IMU carries (a synthetic flight's true bias at imu.t; a recorded one's is not known)
        self.start_bias = (None if imu is None or imu_bias is None else
                           tuple(_interp_rows(self.t_first, imu.t, b) for b in imu_bias))

    def sequence_time(self) -> float:
        """Where in the sequence the vehicle is now (before t_first: the pre-flight)."""
        offset, newest = self.clock[0], self.clock[1]
        if math.isnan(offset):
            return -math.inf
        return min(time.monotonic() - offset, newest + MAX_LEAD_S, self.t_last)

    def state(self, _uptime: float) -> dict:
        """Vehicle.state at the current sequence time (the uptime argument is ignored):
        before the flight still at the start pose (its IMU reads gravity alone), in flight with
        the recorded readings; sensor_message saturates the IMU readings like a real sensor's."""
        t = self.sequence_time()
        if t < self.t_first:  # standing in the pad that holds the first pose
            return self._preflight()
        return with_recordings(self.inner.state(t - self.inner.t0), t, self.imu, self.sensors)

    def _preflight(self) -> dict:
        """Standing at the first pose: the IMU reads gravity plus its bias at the flight's
        start (when known), the attitude the true pose with the mean error the flight's
        attitude has over its first seconds. One attitude sample held for the whole pre-flight
        froze its noise into a tilt the IMU did not show, the fusion took it for a 0.07 m/s^2
        accelerometer bias, and in the climb its horizontal position left the map by 0.6 m
        (sdvl replay, position NEES 15); an IMU without its bias on the ground taught the
        fusion a bias of zero that the take-off then contradicted (NEES 4-5)."""
        state = self.inner.state(self.t_first - 0.5 * PAD_S - self.inner.t0)
        held = state["rotation"]
        state = with_recordings(state, self.t_first, None, self.sensors)
        if self.attitude_error is not None:
            state["rotation"] = self.attitude_error * held
        if self.start_bias is not None:
            state["specific_force"] = state["specific_force"] + self.start_bias[0]
            state["rates"] = state["rates"] + self.start_bias[1]
        return state

    def _mean_attitude_error(self) -> Rotation:
        """The recorded attitude against the true one (N), averaged over the flight's first
        PREFLIGHT_ERRORS_S (or the whole of a shorter one)."""
        times = np.linspace(self.t_first, min(self.t_first + PREFLIGHT_ERRORS_S, self.t_last), 50)
        truth = Rotation.concatenate([self.inner.state(t - self.inner.t0)["rotation"]
                                      for t in times])
        recorded = Rotation.from_quat(self.sensors.attitude[
            [nearest_sample(self.sensors.t, t) for t in times]])
        return (recorded * truth.inv()).mean()


def with_recordings(state: dict, t: float, imu: ImuSamples | None,
                    sensors: SensorSamples | None) -> dict:
    """A Vehicle state at sequence time t with the flight's recorded readings in place of the
    derived ones: a body IMU's, and a synthetic flight's attitude, barometer and rangefinder
    (noise and compass bias included)."""
    if imu is not None:
        state["specific_force"] = _interp_rows(t, imu.t, imu.accel)
        if imu.gyro is not None:
            state["rates"] = _interp_rows(t, imu.t, imu.gyro)
    if sensors is not None:
        i = nearest_sample(sensors.t, t)
        state["rotation"] = Rotation.from_quat(sensors.attitude[i])
        state["baro_alt"] = float(sensors.baro_alt[i])
        state["range"] = float(sensors.range[i]) if sensors.range_valid[i] else None
    return state


def _interp_rows(t: float, times: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.array([np.interp(t, times, values[:, i]) for i in range(values.shape[1])])


@dataclass
class AutopilotOutcome:
    """What the autopilot process hands back: the vision messages it received, its record
    (STATUSTEXTs, events, its own estimate) and the pilot's arming attempts."""

    vision: list[VisionMessage]
    record: AutopilotRecord
    arm_attempts: list[tuple[float, bool]]  # (monotonic time, armed)


def _serve(conn: multiprocessing.connection.Connection, options: SimOptions,
           trajectory: Trajectory | None, recorded: tuple, clock: multiprocessing.Array,
           arm: bool) -> None:
    """The child: sends the autopilot's URL; while the flight has not started, a pilot arms it
    as soon as it lets them (`arm`); on request, its outcome."""
    sim = SimAutopilot(options)
    vehicle = None
    if trajectory is not None:
        vehicle = sim.vehicle = ReplayVehicle(trajectory, clock, *recorded)
    pilot = Pilot(sim) if arm else None
    with sim:
        conn.send(sim.url)
        while not conn.poll(PILOT_TICK_S):
            if pilot is not None and vehicle is not None:
                pilot.tick(time.monotonic(), vehicle.sequence_time() < vehicle.t_first)
        conn.recv()
        conn.send(AutopilotOutcome(
            [VisionMessage(r.msg.get_type(), r.t, r.msg.to_dict()) for r in sim.vision],
            sim.record, pilot.attempts if pilot else []))


def start_context() -> multiprocessing.context.BaseContext:
    """The START_METHOD context whose fork server imports this module (numpy, scipy, pymavlink,
    the simulated autopilot) once, so the processes it starts do not each import them again
    (0.7 s CPU a start)."""
    ctx = multiprocessing.get_context(START_METHOD)
    ctx.set_forkserver_preload(["__main__", __name__])
    return ctx


class AutopilotProcess:
    """Start it, connect the service to `url`, call `finish()` for what it received."""

    def __init__(self, options: SimOptions | None = None,
                 trajectory: Trajectory | None = None, imu: ImuSamples | None = None,
                 sensors: SensorSamples | None = None, arm: bool = False,
                 imu_bias: tuple[np.ndarray, np.ndarray] | None = None):
        ctx = start_context()
        self.clock = ctx.Array("d", [math.nan, math.nan])
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(
            target=_serve, args=(child, options or configured_options(), trajectory,
                                 (imu, sensors, imu_bias),
                                 self.clock, arm),
            name="sim-autopilot", daemon=True)
        self._process.start()
        self.url: str = self._conn.recv()

    def frame_released(self, t_source: float, t_capture: float) -> None:
        """Tell the vehicle which sequence time the newest frame shows."""
        self.clock[0], self.clock[1] = t_capture - t_source, t_source

    def finish(self) -> AutopilotOutcome:
        """Stop the autopilot; what it received and recorded."""
        try:
            self._conn.send("stop")
            return self._conn.recv()
        finally:
            self._process.join(5.0)
            if self._process.is_alive():
                self._process.terminate()
