"""The companion service's parts on a virtual clock, for the deterministic closed loop.

`sdvl run` runs these in threads on CLOCK_MONOTONIC (daemon/service.py); here each runs when the
loop says it is its time: the tracker on each frame (mapping inline, so the run repeats), the
fusion estimator (the config the service would use), ODOMETRY encoded as the service encodes it
(daemon/messages.py), HEARTBEAT at 1 Hz, TIMESYNC answers, the stream requests
(daemon/streams.py) and the EKF origin (daemon/origin.py), all through the service's MAVLink
codec. Only ODOMETRY is sent (the service's default `mavlink.output`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from daemon import messages
from daemon.autopilot_watch import AutopilotWatch
from daemon.config import Config
from daemon.frames import Frame, FrameCheck
from daemon.fusion.estimator import FusionEstimator
from daemon.health import Health
from daemon.mavlink_codec import MavlinkCodec
from daemon.origin import OriginSetter
from daemon.statustext import StatusTexts
from daemon.streams import StreamKeeper
from daemon.tracking import track
from sdvl.errors import InputError
from sim.flight.frames_csv import frame_details
from sim.replay.autopilot_process import VisionMessage

HOUSEKEEPING_S = 0.05  # the service's housekeeping period (daemon/service.py)


@dataclass(frozen=True)
class Tracked:
    """A tracker result waiting for the estimator's turn."""

    index: int
    t_source: float
    t_capture: float
    result: object
    track_s: float


class LockstepCompanion:
    """Our service against `write` (bytes to the autopilot) on the clock `clock()` (our
    monotonic seconds). `sent` holds every vision message as sent, for the report."""

    def __init__(self, config: Config, make_tracker: Callable[[Frame], object],
                 write: Callable[[bytes], None], clock: Callable[[], float]):
        if config.mavlink.output != "odometry":
            raise InputError("sdvl fly sends ODOMETRY: leave mavlink.output at 'odometry'")
        self.cfg, self.clock, self.make_tracker = config, clock, make_tracker
        self.codec = MavlinkCodec(config.mavlink.system_id, config.mavlink.component_id,
                                  self._write, self._on_message)
        self._out = write
        self.watch = AutopilotWatch(config.mavlink.heartbeat_timeout_s)
        self.texts = StatusTexts(config.mavlink.statustext_interval_s, self._send_text)
        self.streams = StreamKeeper(self.codec, self.watch, False,
                                    report=lambda text, sev: self.texts.report(text, clock(),
                                                                               sev))
        self.origin = (OriginSetter(config.origin, self.codec.mav, self.codec.send)
                       if config.origin.enabled else None)
        self.estimator = FusionEstimator(config.fusion, config.mounting,
                                         report=lambda text: self.texts.report(text, clock()),
                                         now=clock)
        self.tracker = None
        self.check = FrameCheck()
        self.sent: list[VisionMessage] = []
        self.rows: list[dict] = []
        self._next_heartbeat = self._next_housekeeping = -np.inf
        self._health = Health.STARTING

    def _write(self, data: bytes) -> bool:
        self._out(data)
        return True

    def _send_text(self, severity: int, text: str) -> bool:
        return self.codec.send(self.codec.mav.statustext_encode(severity, text.encode()))

    def feed(self, data: bytes) -> None:
        """Bytes from the autopilot."""
        self.codec.feed(data)

    def _on_message(self, msg: object) -> None:
        now = self.clock()
        if msg.get_type() == "TIMESYNC" and msg.tc1 == 0:
            self.codec.send(self.codec.mav.timesync_encode(round(now * 1e9), msg.ts1))
        verdict = self.watch.receive(msg, now)  # as the service: only its bound autopilot's
        for event in verdict.events:
            if event in ("reconnected", "rebooted") and self.origin is not None:
                self.origin.restart()
        if not verdict.accepted:
            return
        self.streams.on_message(msg, now)
        if self.origin is not None:
            self.origin.on_message(msg)
        self.estimator.on_autopilot_message(msg)

    def tick(self) -> None:
        """HEARTBEAT and housekeeping when they are due."""
        now = self.clock()
        if now >= self._next_heartbeat:
            self._next_heartbeat = max(self._next_heartbeat + 1.0, now)
            self.codec.send(messages.heartbeat(self.codec.mav,
                                               self._health.report.system_status))
        if now >= self._next_housekeeping:
            self._next_housekeeping = now + HOUSEKEEPING_S
            self.watch.check(now)
            self.streams.tick(now)
            if self.origin is not None:
                target = ((self.watch.system_id, self.watch.component_id)
                          if self.watch.alive else None)
                self.origin.tick(now, target)
            self.texts.flush(now)

    def track(self, index: int, t_source: float, t_capture: float, image: np.ndarray,
              depth: np.ndarray | None = None, orientation: object = None) -> Tracked:
        """Track a frame captured at `t_capture` (our clock), with the depth camera's map
        when it has one (checked as the service's capture thread checks it) and the camera's
        orientation the estimator knew at the capture (`estimator.orientation`, asked on the
        loop's thread so the flight repeats). Only the caller's thread uses the tracker, so it
        may be a worker."""
        frame = Frame(index, t_source, t_capture, image, self.check.depth(depth, image))
        if self.tracker is None:
            self.tracker = self.make_tracker(frame)
        start = time.perf_counter()
        result = track(self.tracker, frame, orientation)
        return Tracked(index, t_source, t_capture, result, time.perf_counter() - start)

    def publish(self, tracked: Tracked) -> None:
        """The estimator's turn for a tracked frame; its estimate goes out as ODOMETRY."""
        result = tracked.result
        self._health = Health.of_tracking(result.quality)
        estimate = self.estimator.on_frame(result, tracked.t_capture)
        if estimate is not None:
            msg = messages.odometry(self.codec.mav, estimate)
            self.codec.send(msg)
            self.sent.append(VisionMessage("ODOMETRY", self.clock(), msg.to_dict()))
        self.rows.append({"t_capture": tracked.t_capture, "t_source": tracked.t_source,
                          "track": tracked.track_s, "sent": estimate is not None,
                          "send": self.clock() - tracked.t_capture if estimate else None,
                          "quality": result.quality, "has_pose": result.has_pose,
                          "new_segment": result.new_segment,
                          "details": frame_details(result, estimate)})

    def close(self) -> None:
        if self.tracker is not None:
            self.tracker.close()
