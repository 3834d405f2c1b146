"""FusionEstimator: the EKF behind the daemon's Estimator seam (daemon/estimate.py).

Autopilot messages are queued as they arrive (asyncio thread) with their arrival time; each
tracker frame (tracking thread) maps their stamps to our clock, applies everything up to the
frame's capture time in time order (replaying the filter for late ones), fuses the frame and
returns an estimate.

The filter starts with the autopilot's first ATTITUDE, once it can tell whether the vehicle
stands still (rest.py), and from then on every frame gives an estimate with the filter's
covariance, before the map exists too: standing on the ground the vehicle is where it started
(zero velocity fused), in a climb before the map the IMU and barometer carry it and the
covariance grows, and while the map's scale is unknown the covariance carries that. So the
autopilot hears from us from power-on (its VisOdom pre-arm check needs that) and never hears a
position surer than the filter is. A map the tracker started from a depth map is in metres
(SceneResult.metric): its scale is 1 with no variance (ScaleSource.METRIC) and none of the scale
fits runs, so its poses count in full from its first frame.

Local frame: NED with the origin at the vehicle's position when the filter starts, at the height
the autopilot itself reports then (LOCAL_POSITION_NED), so the autopilot's height does not step
when it starts using ours; heading from the autopilot's attitude (compass), so it agrees with
the autopilot's own yaw. reset_counter changes only when an estimate jumps from the last one
further than both covariances allow (output.Continuity).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from daemon.config import MountingConfig
from daemon.estimate import VisionEstimate
from daemon.fusion import measurements as m
from daemon.fusion.alignment import AlignmentGate
from daemon.fusion.attitude import AttitudeTrack
from daemon.fusion.clock import ClockMap
from daemon.fusion.config import FusionConfig
from daemon.fusion.imu_gate import ImuGate
from daemon.fusion.imu_noise import ImuNoise
from daemon.fusion.map_fusion import FrameInput, MapFusion, Readings, frame_input
from daemon.fusion.output import Continuity, attitude_noise, build_estimate, horizontal_std
from daemon.fusion.prior_watch import PriorWatch
from daemon.fusion.repeats import Repeats
from daemon.fusion.rest import RestDetector
from daemon.fusion.sensors import (
    BARO_PRIORITY,
    IMU_PRIORITY,
    Attitude,
    Baro,
    Imu,
    LocalPosition,
    Range,
    flight_states,
    parse,
)
from daemon.fusion.source_choice import SourceChoice
from daemon.fusion.state import THETA, VEL, NavFilter
from daemon.fusion.timeline import Event, Timeline
from daemon.mounting import body_from_camera
from vo.result import Quality
from vo.rotation_prior import Orientation

log = logging.getLogger("sdvl.fusion")
# messages waiting for the tracking thread: 10 s of an autopilot streaming 400 a second; older
# ones would be dropped as late anyway (history_s); 20,000 SCALED_IMU messages measured 14 MB
INBOX_LIMIT = 4000
BARO_INTERVAL_S = 0.075  # correlated error: at most ~13 Hz fused (a 10 Hz stream whole, 50 Hz not)
UNDECIDED_START_S = 2.0  # start moving (velocity unknown) if rest is still undecided by then
HEIGHT_FRESH_S = 1.0  # the autopilot's own height this close to the start sets ours


class FusionEstimator:
    """Scale, gravity, heading and velocity for the tracker's poses; see the module doc."""

    def __init__(self, cfg: FusionConfig, mounting: MountingConfig,
                 report: Callable[[str], None] | None = None,
                 now: Callable[[], float] = time.monotonic):
        cfg.check()
        self.cfg = cfg
        self.R_c_b = body_from_camera(mounting).T
        self.now = now
        self.reset_counter = 0
        self.filter = NavFilter(cfg)
        self.gate = AlignmentGate(cfg, report)
        self.attitude = AttitudeTrack(cfg.attitude_timeout_s, cfg.history_s + 2.0, report)
        self.clock = ClockMap(cfg.clock_offset_window_s)
        self.timeline = Timeline(cfg.history_s)
        self.sources: dict[str, str] = {}  # "imu"/"baro" -> the message type fused
        self._choices: dict[str, SourceChoice] = {}
        self._last_baro_t = -math.inf  # time of the last barometer sample fused
        self.imu_gate = ImuGate(report, self._descent)
        self.prior_watch = PriorWatch(report)
        self.imu_noise = ImuNoise(cfg.accel_noise)  # of the stream fused
        self.repeats = Repeats()
        self.dropped_stamps = 0
        self._inbox: deque[tuple[float, object]] = deque(maxlen=INBOX_LIMIT)
        self._lock = threading.Lock()  # the inbox, between the link's thread and ours
        self._new_offset: tuple[float | None] | None = None  # set_clock_offset's, not yet used
        self._filter_lock = threading.Lock()  # the filter, between frames and bridges
        self.first_aligned_s: float | None = None  # when a map's scale first converged
        self.rest = RestDetector(cfg)
        self.continuity = Continuity(cfg.gate_chi2_3dof)
        self._segment = 0
        self._first_attitude_t: float | None = None
        self._autopilot_z: tuple[float, float] | None = None  # (t, NED z) it reports
        self._last_frame_t = float("-inf")
        self.readings = Readings()
        optical_axis = self.R_c_b.T[:, 2]  # in body FRD
        camera_down = optical_axis[2] >= np.cos(np.radians(cfg.range_max_tilt_deg))
        self.maps = MapFusion(cfg, self.filter, self.attitude, self.gate, self.readings,
                              self._imu_fresh, self.imu_noise.density, camera_down)

    # --- the Estimator protocol ---------------------------------------------------------------

    def on_autopilot_message(self, msg: object) -> None:
        """Queue a message with its arrival time; the tracking thread fuses it."""
        with self._lock:
            self._inbox.append((self.now(), msg))

    def set_clock_offset(self, offset_s: float | None) -> None:
        """Our monotonic time minus the autopilot's boot time, from TIMESYNC (seconds); the
        clock map takes it before it maps the next messages (the tracking thread's drain)."""
        with self._lock:
            self._new_offset = (offset_s,)

    def on_frame(self, result: object, t_capture: float) -> VisionEstimate | None:
        """Fuse one tracker FrameResult captured at `t_capture` (our monotonic seconds); the
        estimate to send for that moment, or None."""
        with self._filter_lock:
            return self._on_frame(result, t_capture)

    def orientation(self, t_capture: float) -> Orientation | None:
        """The camera's orientation in NED at a frame's capture time (the autopilot's attitude,
        interpolated or carried by its rates, times the mounting) with the variance of what
        the attitude samples may have missed, for the tracker's rotation prior (tracking
        thread); None without a recent attitude."""
        with self._filter_lock:
            self._drain()
            att = self.attitude.at(t_capture)
        if att is None:
            return None
        return Orientation(att.R_n_b @ self.R_c_b.T, att.gap_var)

    def bridge(self, t: float) -> VisionEstimate | None:
        """An estimate for time t when no frame has come for a while (the tracker is busy, the
        camera stalled), so the autopilot does not go without: the filter carried to t on the
        IMU samples since its last frame, in a copy (the next frame continues from the filter
        itself), with the covariance that grew meanwhile. None without a fresh IMU (nothing
        real would carry it), before the filter started, or when it would be no news."""
        with self._filter_lock:
            self._drain()
            f = self.filter
            if f.t is None or t <= max(f.t, self._last_frame_t):
                return None
            carried = NavFilter(self.cfg)
            carried.restore(f.snapshot())
            for event in self.timeline.pending:
                if event.kind == "imu" and event.t <= t:
                    self._propagate(event.t, carried)
                    carried.accel, carried.t_accel = event.data.accel, event.t
            self._propagate(t, carried)
            att = self.attitude.at(t) or self.attitude.latest
            if att is None or not self._imu_fresh(t, carried):
                return None
            estimate = build_estimate(
                carried, self.cfg, R_l_b=att.R_n_b,
                rot_cov=attitude_noise(self.cfg, Quality.GOOD, att.gap_var),
                rates=att.rates, t_capture=t, t_source=math.nan, state=Quality.GOOD,
                reset_counter=self.reset_counter)
            if estimate is None or horizontal_std(carried) > self.cfg.publish_max_std_m:
                return None
            return self._continuous(estimate)

    def _on_frame(self, result: object, t_capture: float) -> VisionEstimate | None:
        self._drain()
        self.prior_watch.add(result.rotation_prior, t_capture)
        if result.new_segment:
            self._segment += 1
        frame = frame_input(result, self.R_c_b, self._segment, self.cfg.vo_covariance_factor)
        if not np.isfinite(t_capture) or t_capture <= self._last_frame_t:
            return None
        self._last_frame_t = t_capture
        self.timeline.add(t_capture, "frame", frame)  # None: no pose, the filter moves on
        f = self.filter
        self.timeline.run(t_capture, f.t, self._apply, f.restore, f.snapshot)
        if f.t is not None and f.diverged:
            self._restart_diverged(t_capture)
            return None
        if f.t != t_capture:
            self._say_why_not_started(t_capture)
            return None
        tracked = frame is not None and f.segment == frame.segment
        if tracked and self.gate.update(f, t_capture):
            f.converged = True
            self.first_aligned_s = self.first_aligned_s or t_capture
        return self._estimate(result, frame if tracked else None, t_capture)

    def _restart_diverged(self, t: float) -> None:
        """The filter's numbers broke (a starved CPU's long gaps, an input no gate caught):
        nothing it says can be sent; it starts again from the next attitude, as at power-on,
        and the autopilot hears of the jump by the reset counter."""
        log.warning("fusion: the filter diverged at %.1f s (non-finite or negative variance); "
                    "restarting it", t)
        self.filter.reset()
        self.timeline = Timeline(self.cfg.history_s)
        self.gate.restart()
        self.reset_counter += 1

    def _estimate(self, result: object, frame: FrameInput | None,
                  t_capture: float) -> VisionEstimate | None:
        """The estimate at the filter's time: attitude from the map when this frame was fused,
        else the autopilot's; None while the filter does not know where the vehicle is."""
        f, cfg = self.filter, self.cfg
        att = self.attitude.at(t_capture)
        if frame is not None:
            R_l_b = f.R_nom @ frame.R_w_b
            rot_cov = f.P[THETA, THETA] + f.R_nom @ frame.cov[3:, 3:] @ f.R_nom.T
        elif att is not None:
            R_l_b, rot_cov = att.R_n_b, attitude_noise(cfg, result.quality, att.gap_var)
        else:
            return None
        if not self._known(t_capture):
            self.continuity.last = None
            return None
        estimate = build_estimate(
            f, cfg, R_l_b=R_l_b, rot_cov=rot_cov,
            rates=att.rates if att is not None else np.zeros(3), t_capture=t_capture,
            t_source=float(result.t), state=result.quality, reset_counter=self.reset_counter)
        return None if estimate is None else self._continuous(estimate)

    def _known(self, t: float) -> bool:
        """Whether the filter knows where the vehicle is well enough to say so: its horizontal
        std below publish_max_std_m, and something real behind the position: the IMU, standing
        still, or a map whose scale has converged (without an IMU a constant-velocity guess
        carries the filter between map updates, and a map of unknown scale with it makes
        positions surer than they are)."""
        f = self.filter
        if horizontal_std(f) > self.cfg.publish_max_std_m:
            self.gate.waiting("position unknown: nothing sent", t)
            return False
        if self._imu_fresh(t) or f.converged or self.rest.at_rest(t):
            return True
        self.gate.waiting("no IMU and the map not aligned: nothing sent", t)
        return False

    def _say_why_not_started(self, t: float) -> None:
        if self.attitude.latest is None:
            self.gate.waiting("waiting for the autopilot's ATTITUDE", t)

    # --- inputs -------------------------------------------------------------------------------

    def _continuous(self, estimate: VisionEstimate) -> VisionEstimate:
        """The estimate, with a new reset_counter when it jumped from the last one sent."""
        if not self.continuity.jumped(estimate):
            return estimate
        self.reset_counter = (self.reset_counter + 1) % 256
        log.info("fusion: the estimate jumped, reset_counter %d", self.reset_counter)
        return dataclasses.replace(estimate, reset_counter=self.reset_counter)

    def _drain(self) -> None:
        """Autopilot messages -> attitude track and timeline events on our clock. The inbox
        is only emptied under its lock: the link's loop, which queues every message, does not
        wait for the messages' fusion (a first numba call took 1 s on a loaded machine and
        made the loop's messages late enough to be dropped)."""
        with self._lock:
            items = list(self._inbox)
            self._inbox.clear()
            new_offset, self._new_offset = self._new_offset, None
        if new_offset is not None:
            self.clock.set_offset(new_offset[0])
        for arrival, msg in items:
            self._ingest(arrival, msg)

    def _ingest(self, arrival: float, msg: object) -> None:
        states = flight_states(msg)
        for kind, value in states:  # unstamped: their arrival time is close enough
            (self.rest.on_landed if kind == "landed" else self.rest.on_armed)(arrival, value)
        if states:
            return
        parsed = parse(msg)
        if parsed is None:
            return
        remote, samples = parsed
        if self.repeats.seen(msg, remote):
            return
        t = self.clock.to_local(remote, arrival)
        if t is None:
            self.dropped_stamps += 1
            return
        for sample in samples:
            sample = dataclasses.replace(sample, t=t)
            if isinstance(sample, Attitude):
                if self.attitude.add(sample):
                    self.rest.on_rates(t, sample.rates)
                    self.timeline.add(t, "attitude", None)  # late ones replay what used it
            elif isinstance(sample, Imu) and self.cfg.use_imu:
                self._add_imu(sample)
            elif isinstance(sample, LocalPosition):
                self._autopilot_z = (t, float(sample.position[2]))
            elif isinstance(sample, Range) and self.cfg.use_rangefinder:
                self.timeline.add(t, "range", sample)
            elif isinstance(sample, Baro) and self.cfg.use_baro:
                self._add_stream("baro", sample, BARO_PRIORITY)

    def _add_imu(self, sample: Imu) -> None:
        """An IMU sample through the spike gate (imu_gate.py); a touch-down's jolt it saw
        becomes a timeline event."""
        jolts = self.imu_gate.jolts
        if self.imu_gate.admit(sample.source, sample.t, sample.accel):
            self.rest.on_imu(sample.t, sample.accel)
            self._add_stream("imu", sample, IMU_PRIORITY)
        if self.imu_gate.jolts > jolts:
            self.timeline.add(sample.t, "touchdown", None)

    def _add_stream(self, kind: str, sample: Imu | Baro, priority: dict[str, int]) -> None:
        """Fuse one stream of a kind: the preferred one that streams steadily (source_choice)."""
        choice = self._choices.setdefault(kind, SourceChoice(kind, priority))
        if not choice.offer(sample.source, sample.t):
            return
        self.sources[kind] = sample.source
        t = sample.t
        if kind == "imu":
            self.imu_noise.add(sample.t, sample.accel)
            t = self._imu_event_time(sample.t)
        if kind == "baro":
            if abs(sample.t - self._last_baro_t) < BARO_INTERVAL_S:
                return
            self._last_baro_t = sample.t
        self.timeline.add(t, kind, sample)

    def _imu_event_time(self, t: float) -> float:
        """When the filter starts integrating an IMU sample stamped t: half a sample interval
        before it, so each sample stands for the time around it. Held from its own stamp to
        the next, every sample is applied half an interval late (10 ms at 50 Hz), and in a
        climb the filter took that lag of its height for the map's scale (1 %). Not before the
        filter's time."""
        interval = self.imu_noise.interval()
        return t if interval is None else t - 0.5 * interval

    # --- the filter ---------------------------------------------------------------------------

    def _apply(self, event: Event) -> None:
        f = self.filter
        if event.kind == "frame":
            self._apply_frame(event.t, event.data)
            return
        if event.kind == "range":
            self.readings.range = (event.t, event.data.distance)
        elif event.kind == "baro":
            self.readings.baro = (event.t, event.data.altitude)
        if f.t is None:
            if event.kind == "attitude":
                self._start(event.t)
            return
        if event.kind == "attitude":
            return
        self._propagate(event.t)
        if event.kind == "imu":
            f.accel, f.t_accel = event.data.accel, event.t
        elif event.kind == "range":
            att = self.attitude.at(event.t)
            if att is not None:
                m.update_range(f, event.data.distance, att.R_n_b)
        elif event.kind == "baro":
            self._baro(event.t, event.data.altitude)
        elif event.kind == "touchdown":
            # the vehicle stands on its gear: the barometer's offset, bent by the wash through
            # the descent, is re-referenced to the height here instead of pulling it (seed 1
            # without the rangefinder settled 0.45 m below the ground at 0.11 m std)
            f.has_baro = False

    def _baro(self, t: float, altitude: float) -> None:
        """The barometer's altitude, only while no rangefinder measures the height: in flight
        the rotors' wash moves it by up to a metre with the throttle (why ArduPilot has
        BARO1_THST_SCALE; 0.77 m in a hover in sim/autopilot), a bias no white noise covers
        that would pull the height the rangefinder knows to centimetres; nor near the ground,
        where the ground effect moves it by metres (baro_ground_effect_height_m). Its offset
        is re-referenced when it is needed again."""
        if self.readings.fresh_range(t) is None and not self.maps.in_ground_effect():
            m.update_baro(self.filter, altitude)
        else:
            self.filter.has_baro = False

    def _descent(self) -> float:
        """The filter's descent speed (m/s, NED z velocity) now, for the IMU gate's jolts
        (-inf before it starts: no jolt is believed then)."""
        f = self.filter
        return float(f.x[VEL][2]) if f.t is not None else -math.inf

    def _imu_fresh(self, t: float, nav: NavFilter | None = None) -> bool:
        f = nav or self.filter
        return f.accel is not None and t - f.t_accel <= self.cfg.imu_timeout_s

    def _propagate(self, t: float, nav: NavFilter | None = None) -> None:
        """Carry the filter (or `nav`, a copy) to time t on the IMU, or at constant velocity.
        The IMU's sample is turned into N by the attitude half way (at the start, a tilting
        vehicle's acceleration came 6 ms late in the survey's accelerations)."""
        f = nav or self.filter
        att = self.attitude.at(0.5 * (f.t + t)) if self._imu_fresh(t, f) else None
        f.predict(t, f.accel if att is not None else None,
                  att.R_n_b if att is not None else None, self.imu_noise.density())

    def _start(self, t: float) -> None:
        """Start the filter at time t once rest or motion can be told (or the wait is over):
        at the autopilot's own height when it reports one."""
        if self._first_attitude_t is None:
            self._first_attitude_t = t
        still = self.rest.state(t)
        if still is None and t - self._first_attitude_t < UNDECIDED_START_S:
            return
        cfg = self.cfg
        height = (self._autopilot_z[1] if self._autopilot_z is not None
                  and abs(t - self._autopilot_z[0]) <= HEIGHT_FRESH_S else 0.0)
        self.filter.start(t, cfg.rest_velocity_std if still else cfg.start_velocity_std, height)
        self.maps.ground_z = height if still else None
        log.info("fusion: started %s, height %.2f m (NED z %s)",
                 "standing still" if still else "moving", -height,
                 "from the autopilot" if self._autopilot_z is not None else "0")

    def _apply_frame(self, t: float, frame: FrameInput | None) -> None:
        """A frame's time: propagate, fuse zero velocity when standing still, fuse the
        tracker's pose when it has one."""
        f = self.filter
        if f.t is None:
            return
        self._propagate(t)
        if self.rest.at_rest(t):
            m.update_rest(f)
        elif self.rest.on_gear(t):  # spinning up: the IMU stream's folded vibration ran our
            m.update_rest(f, axes=2)  # velocity 0.1 m/s off before lift-off (RESULTS.md)
        if frame is not None:
            self.maps.fuse(t, frame)
