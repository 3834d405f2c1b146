"""`sdvl fly --realtime`: the loaded-machine check. The real service (`Service`, as `sdvl run`
builds it: capture and tracking threads, mapping thread, asyncio link) flies the mission against
the simulated ArduCopter in its own process on the wall clock (CLOCK_MONOTONIC), over UDP, so
threads, the link and the machine's load are real and the latency is measured, not configured.

The camera is a process of its own (camera_process.py) that, at the camera rate, reads the
vehicle's true pose from the autopilot's process (shared memory), stamps the frame then
(exposure), renders it (the rendering time is the camera's readout delay) and hands it to the
service's capture thread. Camera and autopilot are hardware on a drone: their processes run at a
raised priority, so the service competes only with the `--load N` busy processes beside it.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import multiprocessing
import multiprocessing.connection
import select
import time
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega

from daemon.config import Config, replace
from daemon.frames import Frame
from daemon.run_command import tracker_factory
from daemon.service import Service
from sim.autopilot.ports import UdpPort
from sim.autopilot.streams import VISION_MESSAGES
from sim.flight.autopilot_side import AutopilotSide
from sim.flight.camera_process import (
    FrameRing,
    SharedCamera,
    TruthShare,
    camera_process,
    raise_priority,
)
from sim.flight.flight_run import FlightRun, Timing
from sim.flight.loop import flight_config
from sim.flight.mission import Mission
from sim.flight.runner import step_printer
from sim.flight.world import FlightWorld
from sim.replay.autopilot_process import VisionMessage, start_context
from sim.replay.recording import Recorder

WARMUP_FRAMES = 30  # enough for the map to start, so the mapping kernels are compiled too
WARMUP_HEIGHT_M = 3.0
SELECT_S = 0.002
POLL_S = 0.1


def warm_up(world: FlightWorld, make_tracker: Callable[[Frame], object]) -> None:
    """Render and track a short sideways pass at 3 m so the renderer's and the tracker's
    kernels are compiled before the flight's clock starts (a drone's service is up first)."""
    tracker = None
    try:
        for i in range(WARMUP_FRAMES):
            T = np.eye(4)
            T[:3, 3] = (0.0, 0.02 * i, -WARMUP_HEIGHT_M)
            image = world.image(i, i / 30.0, T)
            tracker = tracker or make_tracker(Frame(i, i / 30.0, time.monotonic(), image))
            tracker.process(image, i / 30.0)
    finally:
        if tracker is not None:
            tracker.close()


def _vision(parser: object, data: bytes, arrival: float) -> list[VisionMessage]:
    return [VisionMessage(m.get_type(), arrival, m.to_dict())
            for m in parser.parse_buffer(data) or [] if m.get_type() in VISION_MESSAGES]


def _autopilot_process(conn: multiprocessing.connection.Connection, mission: Mission,
                       seed: int, size: tuple[int, int] | None, without: tuple[str, ...],
                       truth_array: object, timing: Timing, progress: str | None) -> None:
    """The child: the autopilot's end on the wall clock, over UDP; its record on exit."""
    world = FlightWorld.of_preset(mission.world, seed, size)
    truth = TruthShare(truth_array)
    port = UdpPort()
    conn.send(port.url)
    raise_priority("the simulated autopilot")
    conn.recv()  # the service is built: power on
    boot = time.monotonic()
    side = AutopilotSide(mission, world, seed, timing, without, 0.0,
                         progress and step_printer(progress))
    conn.send(boot)
    parser = ardupilotmega.MAVLink(None)
    parser.robust_parsing = True
    vision: list[VisionMessage] = []
    try:
        while not side.done and not conn.poll():
            with contextlib.suppress(OSError, ValueError):
                select.select([port], [], [], SELECT_S)
            data, now = port.read(), time.monotonic()
            if data:
                side.from_companion(data, now - boot)
                vision += _vision(parser, data, now)
            for out in side.step(now - boot):
                port.write(out)
            truth.write(side.now, side.T_ned_body)
    finally:
        port.close()
    conn.send({"steps": side.runner.results, "record": side.model.record,
               "truth": side.truth_trajectory(), "compass": side.compass,
               "viso_delay_ms": side.viso_delay_ms(), "vision": vision})


def _busy() -> None:
    """A process that only burns CPU (the loaded-machine check)."""
    while True:
        pass


async def _serve(service: Service, conn: multiprocessing.connection.Connection) -> None:
    """Run the service until the autopilot's process says the mission has ended."""
    task = asyncio.create_task(service.run())
    while not task.done():
        if conn.poll():
            service.stop()
        await asyncio.wait({task}, timeout=POLL_S)
    task.result()


class CameraHardware:
    """The camera process (camera_process.py) and the service's end of it."""

    def __init__(self, ctx: object, world: FlightWorld, preset: str, seed: int,
                 size: tuple[int, int] | None, depth: bool, truth: TruthShare, fps: float):
        self.ring = FrameRing(world.camera.size[::-1], depth)
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=camera_process, name="sim-camera", daemon=True,
                                   args=(child, preset, seed, size, depth, truth.array,
                                         self.ring.memory.name, self.ring.header, fps))
        self.process.start()
        self.source = SharedCamera(self.conn, self.ring, world.camera)

    def power_on(self, boot: float) -> None:
        """Wait until the renderer is warm, then start exposing on the autopilot's clock."""
        self.conn.recv()
        self.conn.send(boot)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.send("stop")
        self.process.join(5.0)
        if self.process.is_alive():
            self.process.terminate()
        self.ring.close()


def fly_realtime(mission: Mission, config: Config, seed: int, size: tuple[int, int] | None,
                 without: tuple[str, ...], load: int = 0,
                 progress: str | None = None) -> FlightRun:
    """One real-time flight (see the module doc); `progress`: prefix of the step lines on
    stderr (None: none)."""
    world = FlightWorld.of_preset(mission.world, seed, size)
    config = replace(flight_config(config, world),
                     camera={"source": "testpattern", "calibration": ""})
    make_tracker = tracker_factory(config, world.camera)
    warm_up(world, make_tracker)
    timing, truth = Timing(), TruthShare()
    ctx = start_context()
    conn, child = ctx.Pipe()
    process = ctx.Process(target=_autopilot_process, name="sim-autopilot",
                          args=(child, mission, seed, size, without, truth.array, timing,
                                progress), daemon=True)
    process.start()
    camera = CameraHardware(ctx, world, mission.world, seed, size, config.camera.depth, truth,
                            timing.fps)
    busy = [ctx.Process(target=_busy, daemon=True) for _ in range(load)]
    for p in busy:
        p.start()
    try:
        service_config = replace(config, mavlink={"link": conn.recv()})
        recorder = Recorder()
        conn.send("power on")
        boot = conn.recv()
        camera.power_on(boot)
        service = Service(service_config, camera.source, make_tracker, on_tracked=recorder)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        asyncio.run(_serve(service, conn))
        wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
        if not conn.poll():
            conn.send("stop")
        out = conn.recv()
    finally:
        for p in busy:
            p.terminate()
            p.join()
        camera.close()
        process.join(5.0)
        if process.is_alive():
            process.terminate()
    return FlightRun(mission, seed, without, dataclasses.replace(timing, our_clock_s=boot),
                     out["truth"], out["steps"], out["vision"], recorder.rows, out["record"],
                     out["viso_delay_ms"], out["compass"], realtime=True, wall_s=wall_s,
                     cpu_s=cpu_s, load=load, offered=camera.source.offered)
