"""`sdvl faults soak`: the whole service for a long time on a flight flown back and forth, with
its resident memory sampled while it runs (minute 0: the service starts, after the tracker's
warm-up), to show whether anything grows.

A synthetic flight is rendered once to disk, then played forwards, backwards, forwards... (the
path, images, IMU and autopilot sensors mirrored in time, so the drone never jumps and the
tracker keeps one map as long as it can) in real time through the service against the simulated
autopilot, exactly as `sdvl replay --realtime` plays one pass. RSS is read from /proc every
SAMPLE_S seconds; `--tracemalloc` also prints what Python allocated between two moments.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
import tempfile
import threading
import time
import tracemalloc
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from daemon.config import Config, replace
from daemon.run_command import tracker_factory, warm_up
from daemon.service import Service, prefer_handoffs
from sim.autopilot import SimOptions
from sim.datasets.layout import SensorSamples
from sim.replay.autopilot_process import AutopilotProcess
from sim.replay.flight import (
    drone_config,
    recorded_sensors,
    resampled,
    sensor_streams,
    vehicle_trajectory,
)
from sim.replay.harness import ReplaySource
from sim.replay.preflight import WithPreflight
from sim.replay.prerender import prerendered
from sim.replay.replay_run import FirstFrames
from sim.sequence import ImuSamples, Sequence
from sim.trajectory import Trajectory

SAMPLE_S = 10.0
PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20


def rss_mb() -> float:
    """This process's resident memory, MB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE_MB


def _mirrored(t: np.ndarray, loops: int) -> tuple[np.ndarray, np.ndarray]:
    """Times of `loops` passes over the samples at times `t` (forwards, backwards, ...) and the
    index of the sample each shows; the turning sample is not repeated."""
    span = t[-1] - t[0]
    times, index = [t], [np.arange(len(t))]
    for k in range(1, loops):
        order = np.arange(len(t))[::-1] if k % 2 else np.arange(len(t))
        local = (t[-1] - t[order]) if k % 2 else (t[order] - t[0])
        times.append(t[0] + k * span + local[1:])
        index.append(order[1:])
    return np.concatenate(times), np.concatenate(index)


def _mirrored_imu(imu: ImuSamples, loops: int) -> ImuSamples:
    """Accelerations read the same backwards; rotation rates change sign."""
    times, index = _mirrored(imu.t, loops)
    sign = np.ones(len(times))
    start = len(imu.t)
    for k in range(1, loops):
        sign[start:start + len(imu.t) - 1] = -1.0 if k % 2 else 1.0
        start += len(imu.t) - 1
    gyro = None if imu.gyro is None else imu.gyro[index] * sign[:, None]
    return ImuSamples(times, imu.accel[index], gyro)


def back_and_forth(sequence: Sequence, loops: int) -> Sequence:
    """The sequence flown `loops` times, every second pass backwards."""
    times, frames = _mirrored(sequence.timestamps, loops)
    gt = sequence.groundtruth
    gt_t, gt_i = _mirrored(gt.t, loops)
    s = sequence.extras["sensors"]
    s_t, s_i = _mirrored(s.t, loops)
    sensors = SensorSamples(s_t, s.attitude[s_i], s.baro_alt[s_i], s.range[s_i],
                            s.range_valid[s_i])
    keep = ("T_b_c", "world", "gravity", "sensor_noise")
    extras = {k: v for k, v in sequence.extras.items() if k in keep} | {"sensors": sensors}
    load = sequence.image_loader
    return dataclasses.replace(
        sequence, name=f"{sequence.name}-x{loops}", timestamps=times,
        image_loader=lambda i: load(int(frames[i])),
        groundtruth=Trajectory(gt_t, gt.positions[gt_i], gt.quaternions[gt_i]),
        imu=_mirrored_imu(sequence.imu, loops), extras=extras)


@dataclass
class SoakResult:
    """RSS samples (minutes since the start, MB) and what the service did."""

    samples: list[tuple[float, float]]
    frames_offered: int
    frames_tracked: int
    sent: int
    exit_code: int
    top_growth: list[str]
    warnings: Counter = field(default_factory=Counter)  # logger name -> warnings and errors

    def rss_at(self, minute: float) -> float:
        """The sample nearest to `minute`."""
        return min(self.samples, key=lambda s: abs(s[0] - minute))[1]

    def peak(self, start_min: float, end_min: float) -> float:
        """The highest sample from `start_min` to `end_min` (a trimmed heap follows the map
        as it fills and restarts, so one sample is as high as the map was then)."""
        return max((rss for minute, rss in self.samples if start_min <= minute <= end_min),
                   default=float("nan"))

    def per_minute(self) -> list[tuple[int, float]]:
        """The first sample at or after each whole minute."""
        out: dict[int, float] = {}
        for minute, rss in self.samples:
            out.setdefault(int(minute), rss)
        return sorted(out.items())


class _Warnings(logging.Handler):
    """Counts the service's warnings and errors by logger while the soak runs."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.counts: Counter = Counter()

    def emit(self, record: logging.LogRecord) -> None:
        self.counts[record.name] += 1


class _Sampler(threading.Thread):
    def __init__(self, trace_from_min: float | None):
        super().__init__(name="rss-sampler", daemon=True)
        self.samples: list[tuple[float, float]] = []
        self.stopping = threading.Event()
        self.trace_from_min = trace_from_min
        self.first_snapshot: tracemalloc.Snapshot | None = None
        self.t0 = time.monotonic()

    def run(self) -> None:
        self.t0 = time.monotonic()
        while not self.stopping.wait(SAMPLE_S):
            minute = (time.monotonic() - self.t0) / 60.0
            self.samples.append((minute, rss_mb()))
            if self.trace_from_min is not None and self.first_snapshot is None \
                    and minute >= self.trace_from_min:
                self.first_snapshot = tracemalloc.take_snapshot()


def _serve_service(sequence: Sequence, config: Config, frames: int,
                   sampler: _Sampler) -> tuple[int, Service]:
    """The service on the first `frames` frames in real time against the simulated autopilot
    flying the sequence, keeping nothing per frame (unlike the replay's recorder); `sampler`
    runs while the service does (after the tracker's warm-up)."""
    config = replace(drone_config(config, sequence),
                     camera={"source": "testpattern", "calibration": ""})
    make_tracker = tracker_factory(config, sequence.camera)
    warm_up(make_tracker, sequence.camera.width, sequence.camera.height)
    flight = vehicle_trajectory(sequence.groundtruth, config, sequence.extras.get("T_ned_world"))
    # armed after a pre-flight on the ground, as `sdvl replay` flies: a disarmed autopilot
    # says it is landed, and the fusion would hold a flying vehicle still
    autopilot = AutopilotProcess(SimOptions(streams=sensor_streams("ardupilot", flight)),
                                 resampled(flight), arm=True, **recorded_sensors(sequence))
    try:
        config = replace(config, mavlink={"link": autopilot.url})
        source = ReplaySource(WithPreflight(FirstFrames(sequence, frames)), True, 0.0,
                              autopilot.frame_released)
        service = Service(config, source, make_tracker)
        prefer_handoffs()
        sampler.start()
        code = asyncio.run(service.run())
        sampler.stopping.set()
        sampler.join()
    finally:
        autopilot.finish()
    return code, service


def soak(sequence: Sequence, minutes: float, config: Config | None = None,
         trace_from_min: float | None = None) -> SoakResult:
    """Fly `sequence` back and forth for `minutes` through the service in real time."""
    span = float(sequence.timestamps[-1] - sequence.timestamps[0])
    loops = max(1, int(np.ceil(minutes * 60.0 / span)))
    with tempfile.TemporaryDirectory(prefix="sdvl-soak-") as folder:
        rendered, _ = prerendered(sequence, Path(folder), len(sequence), lambda done: None,
                                  alongside=lambda: None)
        looped = back_and_forth(rendered, loops)
        frames = int(np.searchsorted(looped.timestamps, looped.timestamps[0] + minutes * 60))
        if trace_from_min is not None:
            tracemalloc.start(10)
        sampler, warnings = _Sampler(trace_from_min), _Warnings()
        logging.getLogger("sdvl").addHandler(warnings)
        try:
            code, service = _serve_service(looped, config or Config(), frames, sampler)
        finally:
            logging.getLogger("sdvl").removeHandler(warnings)
    growth = []
    if sampler.first_snapshot is not None:
        stats = tracemalloc.take_snapshot().compare_to(sampler.first_snapshot, "traceback")
        growth = ["\n    ".join([f"{s.size_diff / 2**20:+.2f} MB in {s.count_diff:+d} blocks",
                                 *s.traceback.format()[-6:]]) for s in stats[:12]]
        tracemalloc.stop()
    return SoakResult(sampler.samples, service.source.offered, service.stats.frames,
                      service.stats.sent, code, growth, warnings.counts)
