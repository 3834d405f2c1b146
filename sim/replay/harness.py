"""Run a sequence through the whole service (capture thread, tracker, estimator, MAVLink link)
against the simulated autopilot in its own process, and collect what happened.

The service is built like `sdvl run` builds it (daemon.run_command); only the link points at
the simulated autopilot and the frames come from the sequence.
"""

from __future__ import annotations

import asyncio
import dataclasses
import resource
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daemon.camera import SequenceSource, need_depth
from daemon.config import Config, replace
from daemon.run_command import tracker_factory, warm_up
from daemon.service import Service, prefer_handoffs
from sdvl.errors import InputError
from sim.autopilot import SimOptions, configured_options
from sim.replay.autopilot_process import AutopilotProcess
from sim.replay.flight import (
    absent_sensors,
    drone_config,
    is_ned,
    recorded_sensors,
    resampled,
    vehicle_trajectory,
)
from sim.replay.fusion_scores import compass_bias_deg
from sim.replay.lockstep import lockstep_config, run_lockstep
from sim.replay.preflight import WithPreflight, held_before
from sim.replay.prerender import prerendered, renders_on_the_fly
from sim.replay.progress import Progress
from sim.replay.recording import Recorder
from sim.replay.replay_run import FirstFrames, ReplayRun, aligned_time, since_process_start
from sim.trajectory import Trajectory

SETTLE_S = 0.3  # after the last frame, for the last messages to arrive
RATE_MARGIN = 1.05  # fast replay: frames this much slower than the message rate limit


class ReplaySource(SequenceSource):
    """SequenceSource that counts the frames it offers and tells the autopilot's vehicle the
    sequence time of each. As fast as possible still means no faster than `min_interval_s`
    (the service's vision message rate limit), so every estimate reaches the autopilot."""

    def __init__(self, sequence: FirstFrames, realtime: bool, min_interval_s: float,
                 on_frame: Callable[[float, float], None], depth: bool = False):
        super().__init__(sequence, realtime=realtime, depth=depth)
        self.min_interval_s = 0.0 if realtime else min_interval_s * RATE_MARGIN
        self.on_frame = on_frame
        self.offered = 0
        self._last_capture = -np.inf
        self.flight_start_t = getattr(sequence, "start", -np.inf)  # after a pre-flight
        self.flight_start: tuple[float, float] | None = None  # (t_source, t_capture) of it

    def read(self) -> tuple | None:
        item = super().read()
        if item is None:
            return None
        t_source, t_capture, *image_depth = item
        delay = self._last_capture + self.min_interval_s - t_capture
        if delay > 0:
            time.sleep(delay)
            t_capture = time.monotonic()
        self._last_capture = t_capture
        self.offered += 1
        if self.flight_start is None and t_source >= self.flight_start_t:
            self.flight_start = (t_source, t_capture)
        self.on_frame(t_source, t_capture)
        return t_source, t_capture, *image_depth


def during_replay(trajectory: Trajectory, run: ReplayRun) -> Trajectory:
    """The part of a trajectory while frames were played (e.g. with --max-frames)."""
    if not run.rows:
        return trajectory
    times = [r["t_source"] for r in run.rows]
    inside = (trajectory.t >= min(times)) & (trajectory.t <= max(times))
    return trajectory.subset(inside) if inside.sum() >= 2 else trajectory


def choose_estimator(config: Config, sequence: object, estimator: str) -> Config:
    """The config with `[fusion] enabled` set for `estimator`: 'fusion', 'pass-through', or
    'auto' (the config's choice where the sequence has a gravity reference, else
    pass-through)."""
    if estimator == "auto":
        fusion = config.fusion.enabled and is_ned(sequence)
    else:
        fusion = estimator == "fusion"
    return replace(config, fusion={"enabled": fusion})


async def _serve(service: Service, source: ReplaySource, recorder: Recorder,
                 progress: Progress) -> int:
    task = asyncio.create_task(service.run())
    while not task.done():
        rows = recorder.rows
        progress.update(source.offered, len(rows), sum(r["has_pose"] for r in rows))
        await asyncio.wait({task}, timeout=progress.interval_s)
    progress.close()
    return task.result()


@dataclass(frozen=True)
class ReplayPlan:
    """How a sequence is replayed: at its timestamps or not, how many frames, which sensors the
    vehicle lacks and which autopilot it flies: 'ardupilot' or 'px4' set up as check-autopilot
    --apply leaves it (sim.autopilot.configured_options), or one's own SimOptions."""

    realtime: bool
    max_frames: int | None = None
    without: tuple[str, ...] = ()
    autopilot: str | SimOptions = "ardupilot"

    def options(self, flight: Trajectory | None) -> SimOptions:
        """The simulated autopilot: streams only when the service asks (as after a reboot),
        no sensor the flight cannot have (flight.absent_sensors)."""
        absent = absent_sensors(flight, self.without)
        if isinstance(self.autopilot, SimOptions):
            return dataclasses.replace(self.autopilot, absent=absent)
        return configured_options(self.autopilot, requested={}, absent=absent)


def run_replay(sequence: object, config: Config, realtime: bool,
               max_frames: int | None = None, progress: bool = True,
               make_tracker: Callable | None = None, without: tuple[str, ...] = (),
               autopilot: str | SimOptions = "ardupilot") -> ReplayRun:
    """Play `sequence` through the service (its estimator as `config.fusion.enabled` says)
    against the simulated `autopilot`, whose vehicle has no sensor of the kinds in `without`
    (flight.SENSOR_STREAMS); `make_tracker(frame)` replaces the SDVL tracker (tests). Fusion
    without `realtime` runs in lockstep on a virtual clock (sim/replay/lockstep.py)."""
    plan = ReplayPlan(realtime, max_frames, without, autopilot)
    config = replace(drone_config(config, sequence),
                     camera={"source": "testpattern", "calibration": ""})
    lockstep = config.fusion.enabled and not realtime
    if config.camera.depth:
        need_depth(sequence)
    if lockstep:
        if getattr(sequence, "groundtruth", None) is None:
            raise InputError("fusion without --realtime flies the autopilot from the "
                             "sequence's ground truth, and this sequence has none")
        config = lockstep_config(config)
    make_tracker = make_tracker or tracker_factory(config, sequence.camera)
    show = Progress(len(FirstFrames(sequence, max_frames)), progress)
    if lockstep:
        flight = vehicle_trajectory(sequence.groundtruth, config,
                                    sequence.extras.get("T_ned_world"))
        run = run_lockstep(sequence, config, FirstFrames(sequence, max_frames), flight,
                           without, make_tracker, show)
    else:
        run = _replay_with_link(sequence, config, plan, show, make_tracker)
    return dataclasses.replace(run, compass_bias_deg=compass_bias_deg(sequence))


def _replay_with_link(sequence: object, config: Config, plan: ReplayPlan, show: Progress,
                      make_tracker: Callable) -> ReplayRun:
    show.note(f"replay {sequence.name}: warming up the tracker (the first run after an install "
              "compiles its kernels: about a minute)")
    with tempfile.TemporaryDirectory(prefix="sdvl-replay-") as folder:
        if plan.realtime and renders_on_the_fly(sequence):
            show.note(f"replay {sequence.name}: rendering the frames first")
            size = sequence.camera.width, sequence.camera.height
            sequence, warmup_s = prerendered(
                sequence, Path(folder), len(show), show.rendered,
                alongside=lambda: warm_up(make_tracker, *size))
        else:
            warmup_s = warm_up(make_tracker, sequence.camera.width, sequence.camera.height)
        return _replay(sequence, config, plan, show, make_tracker, warmup_s)


def _replay(sequence: object, config: Config, plan: ReplayPlan, show: Progress,
            make_tracker: Callable, warmup_s: float) -> ReplayRun:
    flight = (vehicle_trajectory(sequence.groundtruth, config,
                                 sequence.extras.get("T_ned_world"))
              if sequence.groundtruth is not None else None)
    options = plan.options(flight)
    frames = FirstFrames(sequence, plan.max_frames)
    drone = plan.realtime and config.fusion.enabled and flight is not None
    autopilot = AutopilotProcess(options, None if flight is None else resampled(flight),
                                 arm=drone, **recorded_sensors(sequence))
    if drone:  # it stands on the ground first, powered on, and the pilot arms
        frames = WithPreflight(frames)
        flight = held_before(flight, frames.seconds)
    try:
        config = replace(config, mavlink={"link": autopilot.url})
        source = ReplaySource(frames, plan.realtime, 1.0 / config.mavlink.max_rate_hz,
                              autopilot.frame_released, config.camera.depth)
        recorder = Recorder()
        service = Service(config, source, make_tracker, on_tracked=recorder)
        prefer_handoffs()
        cpu0, wall0 = time.process_time(), time.perf_counter()
        code = asyncio.run(_serve(service, source, recorder, show))
        wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
        time.sleep(SETTLE_S)
    finally:
        outcome = autopilot.finish()
    stats = service.stats
    return ReplayRun(
        name=sequence.name, realtime=plan.realtime, fusion=config.fusion.enabled,
        offered=source.offered, rows=recorder.rows, received=outcome.vision, flight=flight,
        wall_s=wall_s, cpu_s=cpu_s, warmup_s=warmup_s,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, exit_code=code,
        stats={"sent": stats.sent, "skipped_rate": stats.skipped_rate,
               "skipped_stale": stats.skipped_stale,
               "skipped_duplicate": stats.skipped_duplicate,
               "aligned_t": aligned_time(service.estimator, recorder.rows)},
        without=plan.without, autopilot=outcome,
        flight_start=source.flight_start,
        startup_s=since_process_start(recorder.rows[0]["t_capture"]) if recorder.rows else None)
