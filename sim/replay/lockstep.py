"""The fusion replay in lockstep (`sdvl replay --fast` with fusion): deterministic accuracy
figures, independent of the machine's load.

A real-time replay needs the wall clock (the simulated autopilot streams on it) and drops frames
when tracking falls behind, so its numbers move from run to run. Here every frame is tracked in
turn (mapping inline), and the autopilot's messages are made for the sequence's own times on a
virtual clock: the synthetic flight's recorded sensors (IMU with its noise and bias, attitude
with its compass error, barometer with its drift, rangefinder) when it has them, else the
simulated autopilot's readings of the flight. They reach the service's estimator (the same
FusionEstimator, config and mounting as `sdvl run`) in arrival order, and each estimate is
encoded as the ODOMETRY message the service would send, so the report scores it the same way.
Not exercised here: the MAVLink link, rate limiting and timing (the report leaves those None).
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon.camera import sequence_depth
from daemon.config import Config, replace
from daemon.frames import Frame, FrameCheck, LatestSlot
from daemon.fusion.estimator import FusionEstimator
from daemon.messages import odometry
from daemon.tracking import TrackingThread
from sim.autopilot.vehicle import Vehicle, sensor_message
from sim.replay.autopilot_process import VisionMessage, with_recordings
from sim.replay.flight import body_imu, resampled, sensor_streams
from sim.replay.progress import Progress
from sim.replay.replay_run import FirstFrames, ReplayRun, aligned_time
from sim.trajectory import Trajectory

OUR_CLOCK = 1000.0  # our monotonic clock at sequence time 0
BOOT_CLOCK = 10.0  # the autopilot's boot clock at sequence time 0
LINK_LATENCY_S = 0.01  # autopilot message -> companion
RESULT_DELAY_S = 0.03  # frame capture -> tracker result


class RecordedVehicle:
    """The flight as lockstep's autopilot streams it: the motion derived from the flight, with
    the readings the sequence recorded in their place (sim.synth: 200 Hz body IMU, 50 Hz
    attitude, barometer and rangefinder), as the real-time replay's vehicle."""

    def __init__(self, sequence: object, flight: Trajectory):
        self.inner = Vehicle(resampled(flight))
        self.t0 = self.inner.t0
        self.imu = body_imu(sequence)
        self.sensors = sequence.extras.get("sensors")

    def state(self, t: float) -> dict:
        """Vehicle.state at vehicle time t (sequence time t + t0)."""
        return with_recordings(self.inner.state(t), t + self.t0, self.imu, self.sensors)


def autopilot_messages(sequence: object, flight: Trajectory, streams: dict[str, float],
                       end: float) -> list[tuple[float, object]]:
    """(arrival on our clock, message) of every stream up to sequence time `end`, in arrival
    order; stamps on the autopilot's boot clock."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    vehicle = RecordedVehicle(sequence, flight)
    t0 = float(flight.t[0])
    out = []
    for name, hz in streams.items():
        for t in np.arange(t0, end, 1.0 / hz):
            boot_ms = round((t + BOOT_CLOCK) * 1000)
            message = sensor_message(mav, name, float(t) - vehicle.t0, boot_ms, vehicle)
            out.append((t + OUR_CLOCK + LINK_LATENCY_S, message))
    out += flight_state_messages(mav, t0, end)
    out.sort(key=lambda item: item[0])
    return out


def flight_state_messages(mav: mavlink2.MAVLink, t0: float, end: float
                          ) -> list[tuple[float, object]]:
    """(arrival, message) of the autopilot's HEARTBEAT (1 Hz) and EXTENDED_SYS_STATE (5 Hz,
    as the service requests it) for a flight already under way at its first frame: armed, in
    the air."""
    armed = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    out = [(t + OUR_CLOCK + LINK_LATENCY_S, mav.heartbeat_encode(
        mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, armed, 0,
        mavlink2.MAV_STATE_ACTIVE)) for t in np.arange(t0, end, 1.0)]
    out += [(t + OUR_CLOCK + LINK_LATENCY_S, mav.extended_sys_state_encode(
        0, mavlink2.MAV_LANDED_STATE_IN_AIR)) for t in np.arange(t0, end, 0.2)]
    return out


def run_lockstep(sequence: object, config: Config, frames: FirstFrames, flight: Trajectory,
                 without: tuple[str, ...], make_tracker: Callable, show: Progress
                 ) -> ReplayRun:
    """Track every frame in turn and fuse it with the autopilot's messages (all its streams but
    the sensors in `without`) on a virtual clock; the estimates as the ODOMETRY messages the
    service would send."""
    end = float(frames.sequence.timestamps[len(frames) - 1]) + 1.0
    streams = sensor_streams("ardupilot", flight, without)
    messages = autopilot_messages(sequence, flight, streams, end)
    clock = [0.0]
    estimator = FusionEstimator(config.fusion, config.mounting,
                                now=lambda: clock[0])
    estimator.set_clock_offset(OUR_CLOCK - BOOT_CLOCK)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=197)
    rows: list[dict] = []
    received: list[VisionMessage] = []
    k = 0
    # the service's own per-frame step, on this thread (never started: nothing is delivered);
    # the autopilot's messages of the frame's processing time go first, on_frame takes them in
    tracking = TrackingThread(LatestSlot(), make_tracker, estimator, deliver=lambda _: None,
                              on_end=lambda: None)
    check = FrameCheck()  # a depth map the tracker cannot use is counted, the image tracked
    cpu0, wall0 = time.process_time(), time.perf_counter()
    try:
        for index, (t, image) in enumerate(frames.frames()):
            t_capture = t + OUR_CLOCK
            while k < len(messages) and messages[k][0] <= t_capture + RESULT_DELAY_S:
                clock[0] = messages[k][0]
                estimator.on_autopilot_message(messages[k][1])
                k += 1
            clock[0] = t_capture + RESULT_DELAY_S
            depth = (check.depth(sequence_depth(frames, index), image)
                     if config.camera.depth else None)
            tracked = tracking.step(Frame(index, t, t_capture, image, depth))
            if tracked is None:
                continue
            result, estimate = tracked.result, tracked.estimate
            if estimate is not None:
                msg = odometry(mav, estimate)
                received.append(VisionMessage("ODOMETRY", clock[0], msg.to_dict()))
            rows.append({"t_capture": t_capture, "t_source": t, "track": tracked.track_s,
                         "sent": estimate is not None, "send": None, "quality": result.quality,
                         "has_pose": result.has_pose, "new_segment": result.new_segment})
            show.update(index + 1, index + 1, sum(r["has_pose"] for r in rows))
    finally:
        tracking.close_tracker()
        show.close()
    return ReplayRun(
        name=sequence.name, realtime=False, fusion=True, offered=len(rows), rows=rows,
        received=received, flight=flight, wall_s=time.perf_counter() - wall0,
        cpu_s=time.process_time() - cpu0, warmup_s=0.0,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, exit_code=0,
        stats={"sent": len(received), "skipped_stale": 0, "lockstep": True,
               "aligned_t": aligned_time(estimator, rows)}, without=without)


def lockstep_config(config: Config) -> Config:
    """The tracker's mapping inline, so the run is deterministic."""
    return replace(config, service={"mapping_thread": False})
