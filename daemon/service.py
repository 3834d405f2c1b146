"""The companion service: capture and tracking threads, and an asyncio loop that only does I/O.

The loop owns the MAVLink link: vision messages as estimates arrive (never faster than
`max_rate_hz`, never stale, never twice), HEARTBEAT at 1 Hz, TIMESYNC answers, the EKF origin,
STATUSTEXT on state changes, the autopilot heartbeat watchdog and the systemd notifications.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import statistics
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from daemon import messages
from daemon.autopilot_watch import AutopilotWatch
from daemon.camera import CaptureThread, FrameSource
from daemon.config import Config
from daemon.estimate import Estimator, PassThroughEstimator, VisionEstimate
from daemon.frames import Frame, LatestSlot
from daemon.link import open_link
from daemon.mavlink_codec import MavlinkCodec
from daemon.origin import OriginSetter
from daemon.sdnotify import Notifier
from daemon.statustext import StatusTexts
from daemon.streams import StreamKeeper
from daemon.tracking import TrackedFrame, TrackingThread
from sdvl.errors import InputError

log = logging.getLogger("sdvl.service")
HOUSEKEEPING_S = 0.05
NO_FRAMES_S = 1.0  # no processed frame for this long: the camera is gone
THREAD_JOIN_S = 0.7
# A waiting thread gets the GIL within this time (Python's default is 5 ms): a frame or an
# estimate handed between capture, tracking and the loop must not wait for the mapping thread.
GIL_SWITCH_INTERVAL_S = 0.0005
SEVERITY = {"good": mavlink2.MAV_SEVERITY_INFO, "initializing": mavlink2.MAV_SEVERITY_INFO,
            "insufficient": mavlink2.MAV_SEVERITY_WARNING, "bad": mavlink2.MAV_SEVERITY_WARNING,
            "lost": mavlink2.MAV_SEVERITY_CRITICAL, "no camera": mavlink2.MAV_SEVERITY_CRITICAL}
STATE_TEXT = {"good": "tracking good", "initializing": "initializing map",
              "insufficient": "tracking weak", "bad": "tracking bad", "lost": "tracking lost",
              "no camera": "camera lost"}


@dataclass
class ServiceStats:
    """Counters and recent timings, for STATUS lines, tests and the latency benchmark."""

    frames: int = 0
    sent: int = 0
    skipped_rate: int = 0
    skipped_stale: int = 0
    skipped_duplicate: int = 0
    timesync_replies: int = 0
    send_latency_s: deque = field(default_factory=lambda: deque(maxlen=100_000))
    track_s: deque = field(default_factory=lambda: deque(maxlen=100_000))


class Service:
    """Runs until `stop()`, SIGTERM (installed by the caller) or the end of a finite source."""

    def __init__(self, config: Config, source: FrameSource,
                 make_tracker: Callable[[Frame], object], estimator: Estimator | None = None,
                 notifier: Notifier | None = None,
                 on_tracked: Callable[[TrackedFrame, bool], None] | None = None):
        self.cfg = config
        self.source = source
        self.make_tracker = make_tracker
        self.estimator = estimator or self._default_estimator()
        self.notifier = notifier or Notifier()
        self.on_tracked = on_tracked
        self.stats = ServiceStats()
        self.state = "starting"
        self.min_interval_s = 1.0 / config.mavlink.max_rate_hz
        self.codec = MavlinkCodec(config.mavlink.system_id, config.mavlink.component_id,
                                  self._write, self._on_message)
        self.watch = AutopilotWatch(config.mavlink.heartbeat_timeout_s)
        self.origin = (OriginSetter(config.origin, self.codec.mav, self.codec.send)
                       if config.origin.enabled else None)
        self.texts = StatusTexts(config.mavlink.statustext_interval_s, self._send_text)
        self.link = open_link(config.mavlink.link, self.codec.feed)
        self.streams = self._stream_keeper()
        self._last_sent_t: float | None = None
        self._last_frame_time = time.monotonic()
        self._reset_counter = 0
        self._stop = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self.capture: CaptureThread | None = None
        self.tracking: TrackingThread | None = None

    def _stream_keeper(self) -> StreamKeeper:
        """Asks the autopilot for the messages the estimator needs on connect and after a
        reboot, and says which parameter to set when one does not come (daemon/streams.py)."""
        return StreamKeeper(self.codec, self.watch, self.link.spec.usb,
                            report=lambda text, severity: self.texts.report(
                                text, time.monotonic(), severity))

    def _default_estimator(self) -> Estimator:
        """The EKF when [fusion] is enabled, else the pass-through."""
        if not self.cfg.fusion.enabled:
            return PassThroughEstimator(self.cfg.mounting, self.cfg.mavlink)
        from daemon.fusion.estimator import FusionEstimator

        return FusionEstimator(
            self.cfg.fusion, self.cfg.mounting,
            report=lambda text: self._from_thread(self.texts.report, text, time.monotonic()))

    # --- lifecycle -------------------------------------------------------------------------

    async def run(self) -> int:
        """Serve until stopped; 0 on a clean stop, 2 on bad input found late, 1 on a crash."""
        self._loop = asyncio.get_running_loop()
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        self.link.start()
        slot = LatestSlot()
        backoff = (self.cfg.camera.reconnect_min_s, self.cfg.camera.reconnect_max_s)
        self.capture = CaptureThread(self.source, slot, backoff,
                                     on_state=lambda s: self._from_thread(self._set_state, s))
        self.tracking = TrackingThread(slot, self.make_tracker, self.estimator,
                                       deliver=lambda tf: self._from_thread(self._on_tracked, tf),
                                       on_end=lambda: self._from_thread(self._stop.set))
        if not self.source.live:  # a replay as fast as possible must not outrun the link
            while not self.link.connected and not self._stop.is_set():
                await asyncio.sleep(HOUSEKEEPING_S)
        self.capture.start()
        self.tracking.start()
        tasks = [asyncio.create_task(coro) for coro in
                 (self._heartbeats(), self._housekeeping(), self._systemd())]
        self.notifier.notify("READY=1", f"STATUS={self.status_line()}")
        log.info("service started: camera %s, link %s, output %s", self.source.name,
                 self.link.spec, self.cfg.mavlink.output)
        await self._stop.wait()
        await self._shutdown(tasks)
        error = self.tracking.error
        if isinstance(error, InputError):
            log.error("%s", error)
            return 2
        return 1 if error is not None else 0

    def stop(self) -> None:
        """Ask the service to stop (from the loop's thread, e.g. a signal handler)."""
        self._stop.set()

    async def _shutdown(self, tasks: list[asyncio.Task]) -> None:
        self.notifier.notify("STOPPING=1")
        self.capture.stop()
        self.tracking.stop()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for thread in (self.capture, self.tracking):
            await asyncio.to_thread(thread.join, THREAD_JOIN_S)
            if thread.is_alive():
                log.warning("%s thread still busy at stop; leaving it", thread.name)
        await self.link.close()
        log.info("service stopped: %d frames, %d vision messages sent", self.stats.frames,
                 self.stats.sent)

    def _from_thread(self, fn: Callable, *args: object) -> None:
        """Run fn on the loop; ignored once the loop is gone (a thread outliving a stop)."""
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(fn, *args)

    # --- tracking results -> vision messages -------------------------------------------------

    def _set_state(self, state: str) -> None:
        if state == self.state:
            return
        log.info("state: %s -> %s", self.state, state)
        self.state = state
        if state in STATE_TEXT:
            self.texts.report(STATE_TEXT[state], time.monotonic(), SEVERITY[state])

    def _on_tracked(self, tf: TrackedFrame) -> None:
        self.stats.frames += 1
        self.stats.track_s.append(tf.track_s)
        self._last_frame_time = time.monotonic()
        self._set_state(tf.result.quality)
        sent = False
        if tf.estimate is not None:
            if tf.estimate.reset_counter != self._reset_counter:
                self._reset_counter = tf.estimate.reset_counter
                log.info("new map segment: reset_counter %d", self._reset_counter)
                self.texts.report(f"new map, reset {self._reset_counter}", time.monotonic(),
                                  mavlink2.MAV_SEVERITY_NOTICE)
            sent = self._send_estimate(tf.estimate)
        if self.on_tracked is not None:
            self.on_tracked(tf, sent)
        self.tracking.gate.done(tf.t_source)  # the tracker's mapping may go on with this frame

    def _send_estimate(self, e: VisionEstimate) -> bool:
        """Send the vision message(s) for one estimate unless it is a duplicate, too soon
        after the previous one or too old; True when sent."""
        now = time.monotonic()
        last = self._last_sent_t
        if last is not None and e.t_capture <= last:
            self.stats.skipped_duplicate += 1
            return False
        if last is not None and e.t_capture - last < self.min_interval_s:
            self.stats.skipped_rate += 1
            return False
        if now - e.t_capture > self.cfg.mavlink.max_latency_s:
            self.stats.skipped_stale += 1
            return False
        mav, output = self.codec.mav, self.cfg.mavlink.output
        if output in ("odometry", "both"):
            self.codec.send(messages.odometry(mav, e))
        if output in ("vision_position", "both"):
            self.codec.send(messages.vision_position(mav, e))
            if self.cfg.mavlink.vision_speed:
                self.codec.send(messages.vision_speed(mav, e))
        self._last_sent_t = e.t_capture
        self.stats.sent += 1
        self.stats.send_latency_s.append(time.monotonic() - e.t_capture)
        return True

    # --- the link -------------------------------------------------------------------------

    def _write(self, data: bytes) -> bool:
        return self.link.write(data)

    def _send_text(self, severity: int, text: str) -> bool:
        return self.codec.send(self.codec.mav.statustext_encode(severity, text.encode()))

    def _on_message(self, msg: object) -> None:
        now = time.monotonic()
        if msg.get_type() == "TIMESYNC" and msg.tc1 == 0:
            self.codec.send(self.codec.mav.timesync_encode(time.monotonic_ns(), msg.ts1))
            self.stats.timesync_replies += 1
        for event in self.watch.on_message(msg, now):
            self._autopilot_event(event, now)
        self.streams.on_message(msg, now)
        if self.origin is not None:
            text = self.origin.on_message(msg)
            if text:
                self.texts.report(text, now)
        self.estimator.on_autopilot_message(msg)

    def _autopilot_event(self, event: str, now: float) -> None:
        watch = self.watch
        if event == "lost":
            log.warning("autopilot heartbeat lost for %.1f s", watch.timeout_s)
            return
        log.info("autopilot %s: system %d component %d (%s)", event, watch.system_id,
                 watch.component_id, watch.flavour)
        if event in ("reconnected", "rebooted"):
            if self.origin is not None:
                self.origin.restart()
            self.texts.report(f"autopilot {event}", now)

    # --- periodic tasks -------------------------------------------------------------------

    async def _heartbeats(self) -> None:
        """HEARTBEAT at exactly 1 Hz on the loop clock (no drift from send times), the first
        as soon as the link is open."""
        loop = asyncio.get_running_loop()
        while not self.link.connected:
            await asyncio.sleep(HOUSEKEEPING_S)
        due = loop.time()
        while True:
            self.codec.send(messages.heartbeat(self.codec.mav, self.heartbeat_state()))
            due += 1.0
            await asyncio.sleep(max(0.0, due - loop.time()))

    def heartbeat_state(self) -> str:
        """The health reported in HEARTBEAT.system_status."""
        return self.state if self.state in messages.SYSTEM_STATUS else "starting"

    async def _housekeeping(self) -> None:
        while True:
            now = time.monotonic()
            for event in self.watch.check(now):
                self._autopilot_event(event, now)
            self.streams.tick(now)
            if self.origin is not None:
                target = ((self.watch.system_id, self.watch.component_id)
                          if self.watch.alive else None)
                self.origin.tick(now, target)
            if self.state != "starting" and now - self._last_frame_time > NO_FRAMES_S:
                self._set_state("no camera")
            self.texts.flush(now)
            await asyncio.sleep(HOUSEKEEPING_S)

    async def _systemd(self) -> None:
        """WATCHDOG=1 while both threads live; STATUS= every status_interval_s."""
        interval = self.cfg.service.status_interval_s
        if self.notifier.watchdog_interval_s:
            interval = min(interval, self.notifier.watchdog_interval_s)
        while True:
            await asyncio.sleep(interval)
            if self.capture.is_alive() and self.tracking.is_alive():
                self.notifier.notify("WATCHDOG=1", f"STATUS={self.status_line()}")

    def status_line(self) -> str:
        """One line for `systemctl status`."""
        s = self.stats
        link = ("autopilot ok" if self.watch.alive else "no autopilot")
        dropped = self.capture.slot.dropped if self.capture else 0
        recent = list(itertools.islice(reversed(s.send_latency_s), 100))
        latency = f", latency {1e3 * statistics.median(recent):.0f} ms" if recent else ""
        return (f"{self.state}; frames {s.frames}, sent {s.sent}, dropped {dropped}{latency}; "
                f"{link}" + ("; origin set" if self.origin and self.origin.confirmed else ""))
