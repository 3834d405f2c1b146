"""The companion service: capture and tracking threads, and an asyncio loop that only does I/O.

The loop owns the MAVLink link: vision messages as estimates arrive (never faster than
`max_rate_hz`, never stale, never twice, never a value that is not finite), HEARTBEAT at 1 Hz,
TIMESYNC answers, the EKF origin, STATUSTEXT on state changes, the autopilot watch (one bound
autopilot, autopilot_watch.py), the health of camera and threads (health.py) and the systemd
notifications. Exit codes: 0 stopped, 1 a fault systemd should restart it for, 2 a
configuration a human must fix (systemd/README.md).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import statistics
import sys
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon import logs, messages
from daemon.autopilot_watch import AutopilotWatch, Event
from daemon.camera import CaptureThread, FrameSource
from daemon.config import Config, changed_keys, replace
from daemon.estimate import Estimator, PassThroughEstimator, VisionEstimate
from daemon.frame_recorder import FrameRecorder
from daemon.frames import BadFrame, Frame, FrameCheck, LatestSlot
from daemon.health import Fault, Health, HealthCheck
from daemon.heap import HeapTrim
from daemon.link import open_link
from daemon.mavlink_codec import MavlinkCodec
from daemon.obstacle_feed import ObstacleFeed
from daemon.obstacles import obstacle_distance
from daemon.origin import OriginSetter
from daemon.sdnotify import Notifier
from daemon.statustext import PREFIX, StatusTexts
from daemon.streams import StreamKeeper
from daemon.tracking import TrackedFrame, TrackingThread
from sdvl.errors import InputError

log = logging.getLogger("sdvl.service")
HOUSEKEEPING_S = 0.05
BRIDGE_AFTER_S = 0.12  # PX4 restarts vision fusion after 200 ms between samples (EV_MAX_INTERVAL)
BRIDGE_MAX_S = 1.0  # a longer gap is an outage the autopilot's own failsafe must see
THREAD_JOIN_S = 0.7
# the recorder's queue (a second of frames) written at stop; with the threads' joins well under
# systemd's TimeoutStopSec (5 s); the lists name only written images, so a cut-off end still plays
RECORDER_FLUSH_S = 2.0
# READY waits this long for a first usable frame, so a calibration that does not fit the frames
# is reported (exit code 2) before systemd is told the service runs; well under TimeoutStartSec
FIRST_FRAME_WAIT_S = 20.0
# A waiting thread gets the GIL within this time (Python's default is 5 ms): a frame or an
# estimate handed between capture, tracking and the loop must not wait for the mapping thread.
GIL_SWITCH_INTERVAL_S = 0.0005
EXIT_FAULT, EXIT_CONFIG = 1, 2


def prefer_handoffs() -> None:
    """Process-wide: threads hand the GIL over within GIL_SWITCH_INTERVAL_S. Called once by
    whatever hosts a Service in real time (sdvl run, the replay, the latency bench, the soak),
    not by the Service, which tests also run inside other processes."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
RELOADABLE = ("service.log_level", "mavlink.statustext_interval_s")


@dataclass
class ServiceStats:
    """Counters and recent send latencies, for STATUS lines and tests."""

    frames: int = 0
    sent: int = 0
    skipped_rate: int = 0
    skipped_stale: int = 0
    skipped_duplicate: int = 0
    skipped_not_finite: int = 0
    skipped_no_link: int = 0  # estimates the link could not take (not open yet, or gone)
    bridged: int = 0  # estimates carried over a stall of the camera or tracker
    obstacle_scans: int = 0  # OBSTACLE_DISTANCE messages sent
    timesync_replies: int = 0
    message_errors: Counter = field(default_factory=Counter)  # "ATTITUDE: ValueError" -> n
    send_latency_s: deque = field(default_factory=lambda: deque(maxlen=100))


def not_finite(e: VisionEstimate) -> bool:
    """Whether any value the vision messages carry is NaN or infinite."""
    return not all(np.all(np.isfinite(a)) for a in (
        e.position, e.R_local_body, e.velocity_local, e.velocity_body, e.angular_rate,
        e.pose_covariance, e.velocity_covariance))


class Service:
    """Runs until `stop()`, SIGTERM (installed by the caller), the end of a finite source, or
    a fault (`exit_code` says which)."""

    def __init__(self, config: Config, source: FrameSource,
                 make_tracker: Callable[[Frame], object], estimator: Estimator | None = None,
                 notifier: Notifier | None = None,
                 on_tracked: Callable[[TrackedFrame, bool], None] | None = None,
                 size_ok: Callable[[int, int], None] | None = None,
                 recorder: FrameRecorder | None = None):
        self.cfg = config
        self.recorder = recorder  # camera.record: the accepted frames written to disk
        self.source = source
        self.make_tracker = make_tracker
        self.estimator = estimator or self._default_estimator()
        self.notifier = notifier or Notifier()
        self.on_tracked = on_tracked
        self.size_ok = size_ok  # raises InputError for a frame size the calibration cannot fit
        self.stats = ServiceStats()
        self.state = Health.STARTING
        self.fault: Fault | None = None
        self.health = HealthCheck(config.camera.stall_timeout_s, config.mavlink.max_latency_s)
        self.min_interval_s = 1.0 / config.mavlink.max_rate_hz
        mav = config.mavlink
        self.codec = MavlinkCodec(mav.system_id, mav.component_id, self._write,
                                  self._on_message)
        self.watch = AutopilotWatch(mav.heartbeat_timeout_s, mav.autopilot_system_id,
                                    mav.autopilot_component_id,
                                    own=(mav.system_id, mav.component_id))
        self.origin = (OriginSetter(config.origin, self.codec.mav, self.codec.send)
                       if config.origin.enabled else None)
        self.texts = StatusTexts(mav.statustext_interval_s, self._send_text)
        self.link = open_link(mav.link, self.codec.feed)
        self.streams = self._stream_keeper()
        self.heap = HeapTrim()  # freed memory back to the system (a long run's holes)
        self._last_sent_t: float | None = None
        self._last_frame_sent_t: float | None = None  # capture time of the last tracked frame sent
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
        """Serve until stopped; the exit code (0 stopped, 1 fault, 2 configuration)."""
        self._loop = asyncio.get_running_loop()
        self.link.start()
        self._make_threads()
        if not self.source.live:  # a replay as fast as possible must not outrun the link
            while not self.link.connected and not self._stop.is_set():
                await asyncio.sleep(HOUSEKEEPING_S)
        if self.recorder is not None:
            self.recorder.start()
        self.capture.start()
        self.tracking.start()
        tasks = [asyncio.create_task(coro) for coro in (self._heartbeats(), self._housekeeping())]
        await self._first_frame()
        if not self._stop.is_set():
            tasks.append(asyncio.create_task(self._systemd()))
            self.notifier.notify("READY=1", f"STATUS={self.status_line()}")
            log.info("service started: camera %s, link %s, output %s", self.source.name,
                     self.link.spec, self.cfg.mavlink.output)
        await self._stop.wait()
        await self._shutdown(tasks)
        return self.exit_code()

    def _make_threads(self) -> None:
        slot = LatestSlot()
        backoff = (self.cfg.camera.reconnect_min_s, self.cfg.camera.reconnect_max_s)
        check = FrameCheck(self.size_ok,
                           on_first_bad=lambda kind: self._from_thread(self._bad_frames, kind))
        self.capture = CaptureThread(self.source, slot, backoff,
                                     on_state=lambda s: self._from_thread(self._set_state, s),
                                     check=check,
                                     record=self.recorder.offer if self.recorder else None)
        self.tracking = TrackingThread(slot, self.make_tracker, self.estimator,
                                       deliver=lambda tf: self._from_thread(self._on_tracked, tf),
                                       on_end=lambda: self._from_thread(self._stop.set),
                                       obstacles=(ObstacleFeed(self.cfg)
                                                  if self.cfg.obstacles.enabled else None))

    async def _first_frame(self) -> None:
        """Wait until the first frame passed its checks (its size against the calibration),
        the service stops, or FIRST_FRAME_WAIT_S passed (a camera still away: reported and
        retried while the service runs)."""
        deadline = time.monotonic() + FIRST_FRAME_WAIT_S
        while (self.capture.last_frame_t is None and not self._stop.is_set()
               and time.monotonic() < deadline):
            await asyncio.sleep(HOUSEKEEPING_S)

    def exit_code(self) -> int:
        """0 after a stop or the end of a finite source, 2 for a configuration a human must fix
        (said in one line), 1 for any other fault (said in one line)."""
        for thread in (self.capture, self.tracking):
            if isinstance(thread.error, InputError):
                log.error("%s", thread.error)
                return EXIT_CONFIG
        fault = self.fault or self.health.check(time.monotonic(), self.capture, self.tracking)
        if isinstance(fault, Fault):
            self._fail(fault)
            return EXIT_FAULT
        return 0

    def stop(self) -> None:
        """Ask the service to stop (from the loop's thread, e.g. a signal handler)."""
        self._stop.set()

    def reload(self, config: Config) -> None:
        """Take what a changed configuration can change while running (SIGHUP): the log level
        and the STATUSTEXT interval; every other change is named as needing a restart."""
        changed = changed_keys(self.cfg, config)
        applied = [key for key in changed if key in RELOADABLE]
        logging.getLogger().setLevel(config.service.log_level.upper())
        texts_interval = self.texts.interval_s = config.mavlink.statustext_interval_s
        self.cfg = replace(self.cfg, service={"log_level": config.service.log_level},
                           mavlink={"statustext_interval_s": texts_interval})
        restart = [key for key in changed if key not in RELOADABLE]
        log.warning("SIGHUP: configuration reread; applied: %s; need a restart (systemctl "
                    "restart sdvl-companion): %s", ", ".join(applied) or "nothing",
                    ", ".join(restart) or "nothing")

    async def _shutdown(self, tasks: list[asyncio.Task]) -> None:
        self.notifier.stopping()
        self.capture.stop()
        self.tracking.stop()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for thread in (self.capture, self.tracking):
            await asyncio.to_thread(thread.join, THREAD_JOIN_S)
            if thread.is_alive():
                log.warning("%s thread still busy at stop; leaving it", thread.name)
        if self.recorder is not None:
            await asyncio.to_thread(self.recorder.stop, RECORDER_FLUSH_S)
        await self.link.close()
        log.info("service stopped: %d frames, %d vision messages sent", self.stats.frames,
                 self.stats.sent)

    def _from_thread(self, fn: Callable, *args: object) -> None:
        """Run fn on the loop; ignored once the loop is gone (a thread outliving a stop)."""
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(fn, *args)

    # --- health ----------------------------------------------------------------------------

    def _set_state(self, state: Health) -> None:
        if state == self.state or self.fault is not None:
            return
        log.info("state: %s -> %s", self.state, state)
        self.state = state
        report = state.report
        if report.text is not None:
            self.texts.report(report.text, time.monotonic(), report.severity)

    def _fail(self, fault: Fault) -> None:
        """Say what cannot be recovered from, in one log line, a HEARTBEAT and a STATUSTEXT
        sent at once; stop the watchdog and the service (exit code 1: systemd restarts it)."""
        if self.fault is not None:
            return
        self.fault = fault
        log.info("state: %s -> %s", self.state, fault.health)
        self.state = fault.health
        log.error("%s: stopping the watchdog and exiting (code 1) for systemd to restart the "
                  "service", fault.reason)
        report = fault.health.report
        self.codec.send(messages.heartbeat(self.codec.mav, report.system_status))
        self._send_text(report.severity, PREFIX + report.text)
        self.notifier.notify(f"STATUS={fault.health}: {fault.reason}")
        self._stop.set()

    def _bad_frames(self, kind: BadFrame) -> None:
        self.texts.notice(f"skipping {kind} frames", time.monotonic())

    def _check_health(self, now: float) -> None:
        verdict = self.health.check(now, self.capture, self.tracking)
        if isinstance(verdict, Fault):
            self._fail(verdict)
        elif verdict is not None:
            self._set_state(verdict)

    # --- tracking results -> vision messages -------------------------------------------------

    def _on_tracked(self, tf: TrackedFrame) -> None:
        self.stats.frames += 1
        if getattr(tf.result, "merged", None) is not None:
            # the poses go on in the current map's world: nothing to reset
            log.info("the map from before the last re-initialisation is joined to this one")
        self._set_state(self.health.on_frame(time.monotonic(), tf.t_capture,
                                             tf.result.quality))
        sent = tf.estimate is not None and self._deliver(tf.estimate)
        if sent:
            self._last_frame_sent_t = tf.estimate.t_capture
        if tf.obstacles is not None:
            self.codec.send(obstacle_distance(self.codec.mav, tf.obstacles))
            self.stats.obstacle_scans += 1
        if self.on_tracked is not None:
            self.on_tracked(tf, sent)
        self.tracking.gate.done(tf.t_source)  # the tracker's mapping may go on with this frame

    def _bridge(self, now: float) -> None:
        """When no tracked frame's estimate has gone out for BRIDGE_AFTER_S (a busy tracker, a
        stalled camera), send the estimator's carried-forward one each tick, for at most
        BRIDGE_MAX_S."""
        last = self._last_frame_sent_t
        if last is None or not BRIDGE_AFTER_S <= now - last <= BRIDGE_MAX_S:
            return
        estimate = self.estimator.bridge(now)
        if estimate is not None and self._deliver(estimate):
            self.stats.bridged += 1

    def _deliver(self, e: VisionEstimate) -> bool:
        """Say a new map segment when reset_counter changes, then send; True when sent."""
        if e.reset_counter != self._reset_counter:
            self._reset_counter = e.reset_counter
            log.info("new map segment: reset_counter %d", self._reset_counter)
            self.texts.report(f"new map, reset {self._reset_counter}", time.monotonic(),
                              mavlink2.MAV_SEVERITY_NOTICE)
        return self._send_estimate(e)

    def _send_estimate(self, e: VisionEstimate) -> bool:
        """Send the vision message(s) for one estimate unless it is a duplicate, too soon
        after the previous one, too old or not finite; True when sent."""
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
        if not_finite(e):
            self.stats.skipped_not_finite += 1
            if self.stats.skipped_not_finite == 1:
                log.error("an estimate with NaN or infinity was not sent (counted from now on)")
            return False
        mav, output = self.codec.mav, self.cfg.mavlink.output
        taken = []
        if output in ("odometry", "both"):
            taken.append(self.codec.send(messages.odometry(mav, e)))
        if output in ("vision_position", "both"):
            taken.append(self.codec.send(messages.vision_position(mav, e)))
            if self.cfg.mavlink.vision_speed:
                self.codec.send(messages.vision_speed(mav, e))
        if not any(taken):  # the link is not open (yet, or any more): nothing went out
            self.stats.skipped_no_link += 1
            return False
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
        """One decoded message; an error while handling it is counted and logged (the first
        of each kind with its traceback), never left to the transport (asyncio closes a TCP
        connection whose protocol raised)."""
        try:
            self._handle_message(msg)
        except Exception as exc:
            key = f"{msg.get_type()}: {type(exc).__name__}"
            self.stats.message_errors[key] += 1
            if self.stats.message_errors[key] == 1:
                log.error("handling %s failed (%s); counted, logged once", msg.get_type(), exc,
                          exc_info=exc)

    def _handle_message(self, msg: object) -> None:
        """TIMESYNC requests are answered whoever asks; everything else is used only when it
        comes from the bound autopilot (autopilot_watch.py)."""
        now = time.monotonic()
        if msg.get_type() == "TIMESYNC" and msg.tc1 == 0:
            self.codec.send(self.codec.mav.timesync_encode(time.monotonic_ns(), msg.ts1))
            self.stats.timesync_replies += 1
        verdict = self.watch.receive(msg, now)
        for event in verdict.events:
            self._autopilot_event(event, now)
        if not verdict.accepted:
            return
        self.streams.on_message(msg, now)
        if self.origin is not None:
            text = self.origin.on_message(msg)
            if text:
                self.texts.report(text, now)
        self.estimator.on_autopilot_message(msg)

    def _autopilot_event(self, event: Event, now: float) -> None:
        watch = self.watch
        if event is Event.LOST:
            log.warning("autopilot heartbeat lost for %.1f s", watch.timeout_s)
            return
        if event is Event.CLOCK_JUMPED:
            log.warning("autopilot boot clock jumped %+.1f s without a reboot",
                        watch.clock.jump_s)
            return
        log.info("autopilot %s: system %d component %d (%s)", event, watch.system_id,
                 watch.component_id, watch.flavour)
        if event in (Event.RECONNECTED, Event.REBOOTED):
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
            self.codec.send(messages.heartbeat(self.codec.mav, self.state.report.system_status))
            due += 1.0
            await asyncio.sleep(max(0.0, due - loop.time()))

    async def _housekeeping(self) -> None:
        while True:
            now = time.monotonic()
            for event in self.watch.check(now):
                self._autopilot_event(event, now)
            self.streams.tick(now)
            self._bridge(now)
            if self.origin is not None:
                target = ((self.watch.system_id, self.watch.component_id)
                          if self.watch.alive else None)
                self.origin.tick(now, target)
            self._check_health(now)
            self.texts.flush(now)
            if self.heap.due(now):
                asyncio.get_running_loop().run_in_executor(None, self.heap.trim_now)
            await asyncio.sleep(HOUSEKEEPING_S)

    async def _systemd(self) -> None:
        """WATCHDOG=1 while both threads live and nothing is blocked (a fault stops it);
        STATUS= every status_interval_s."""
        interval = self.cfg.service.status_interval_s
        if self.notifier.watchdog_interval_s:
            interval = min(interval, self.notifier.watchdog_interval_s)
        while True:
            await asyncio.sleep(interval)
            if self.fault is None and self.capture.is_alive() and self.tracking.is_alive():
                self.notifier.notify("WATCHDOG=1", f"STATUS={self.status_line()}")

    def status_line(self) -> str:
        """One line for `systemctl status`."""
        s = self.stats
        link = ("autopilot ok" if self.watch.alive else "no autopilot")
        dropped = self.capture.slot.dropped if self.capture else 0
        recent = list(itertools.islice(reversed(s.send_latency_s), 100))
        latency = f", latency {1e3 * statistics.median(recent):.0f} ms" if recent else ""
        bad = sum(self.capture.check.counts.values()) if self.capture else 0
        bad_depth = sum(self.capture.check.depth_counts.values()) if self.capture else 0
        ignored = sum(self.watch.ignored.values())
        lost_lines = logs.dropped_total()
        return (f"{self.state}; frames {s.frames}, sent {s.sent}, dropped {dropped}, bad {bad}"
                + (f", depth unused {bad_depth}" if bad_depth else "")
                + f"{latency}; {link}, ignored {ignored}"
                + ("; origin set" if self.origin and self.origin.confirmed else "")
                + (f"; {lost_lines} log lines lost" if lost_lines else ""))
