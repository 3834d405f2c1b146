"""The service's health: what HEARTBEAT.system_status, STATUSTEXT and `systemctl status` say.

The tracker's own quality states, plus what can be wrong around it: no camera, a camera that
never answers, frames that cannot be used, a CPU too busy to track in time, a failure the
service cannot recover from (systemd restarts it). The MAV_STATE values follow the companion
status convention PX4 documents for a VIO component (ACTIVE usable, CRITICAL degraded,
FLIGHT_TERMINATION nothing usable; docs/en/computer_vision/visual_inertial_odometry.md).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from sdvl.errors import InputError
from vo.result import Quality

NO_FRAMES_S = 1.0  # no frame tracked for this long: something is wrong, say what


class Health(enum.StrEnum):
    """One state; the value is the name used in logs and the systemd status line."""

    STARTING = "starting"
    INITIALIZING = "initializing"
    GOOD = "good"
    INSUFFICIENT = "insufficient"
    BAD = "bad"
    LOST = "lost"
    NO_CAMERA = "no camera"
    CAMERA_BLOCKED = "camera blocked"
    BAD_FRAMES = "bad frames"
    CPU_STARVED = "cpu starved"
    FAILED = "failed"

    @classmethod
    def of_tracking(cls, quality: Quality) -> Health:
        """The state for a tracker quality (vo.result.FrameResult.quality)."""
        return cls(quality) if quality in tuple(Quality) else cls.BAD

    @property
    def report(self) -> Report:
        return REPORTS[self]


@dataclass(frozen=True)
class Report:
    """How a state is told to the autopilot and the ground station."""

    text: str | None  # STATUSTEXT on entering the state (None: nothing to say)
    severity: int  # MAV_SEVERITY of that text
    system_status: int  # HEARTBEAT.system_status (MAV_STATE)


_INFO, _WARNING = mavlink2.MAV_SEVERITY_INFO, mavlink2.MAV_SEVERITY_WARNING
_CRITICAL, _EMERGENCY = mavlink2.MAV_SEVERITY_CRITICAL, mavlink2.MAV_SEVERITY_EMERGENCY
_UNUSABLE = mavlink2.MAV_STATE_FLIGHT_TERMINATION
REPORTS = {
    Health.STARTING: Report(None, _INFO, mavlink2.MAV_STATE_BOOT),
    Health.INITIALIZING: Report("initializing map", _INFO, mavlink2.MAV_STATE_STANDBY),
    Health.GOOD: Report("tracking good", _INFO, mavlink2.MAV_STATE_ACTIVE),
    Health.INSUFFICIENT: Report("tracking weak", _WARNING, mavlink2.MAV_STATE_CRITICAL),
    Health.BAD: Report("tracking bad", _WARNING, mavlink2.MAV_STATE_CRITICAL),
    Health.LOST: Report("tracking lost", _CRITICAL, _UNUSABLE),
    Health.NO_CAMERA: Report("camera lost", _CRITICAL, _UNUSABLE),
    Health.CAMERA_BLOCKED: Report("camera not answering", _CRITICAL, _UNUSABLE),
    Health.BAD_FRAMES: Report("camera frames unusable", _CRITICAL, _UNUSABLE),
    Health.CPU_STARVED: Report("CPU overloaded, poses late", _CRITICAL, _UNUSABLE),
    Health.FAILED: Report("failed, restarting", _EMERGENCY, _UNUSABLE),
}


@dataclass(frozen=True)
class Fault:
    """A failure the service cannot recover from by itself: said in one line, then the
    service stops its watchdog and exits with code 1 so that systemd restarts it."""

    health: Health
    reason: str


class HealthCheck:
    """Tells apart what stops poses: the camera gone, its device not answering, frames that
    cannot be used, frames captured but not tracked in time (a starved CPU), a thread that
    died or hangs. `on_frame` is told of every tracked frame, `check` asks the threads."""

    def __init__(self, stall_timeout_s: float, max_latency_s: float,
                 no_frames_s: float = NO_FRAMES_S):
        self.stall_timeout_s = stall_timeout_s
        self.max_latency_s = max_latency_s
        self.no_frames_s = no_frames_s
        self.last_frame_t: float | None = None  # loop time of the last tracked frame
        self._timely_t: float | None = None  # ... of the last one tracked within max_latency
        self.late_frames = 0

    def on_frame(self, now: float, t_capture: float, quality: str) -> Health:
        """The state after one tracked frame: the tracker's quality, or CPU_STARVED when
        every frame for no_frames_s came later than max_latency_s after its capture."""
        self.last_frame_t = now
        if now - t_capture <= self.max_latency_s or self._timely_t is None:
            self._timely_t = now
        if now - t_capture > self.max_latency_s:
            self.late_frames += 1
        if now - self._timely_t > self.no_frames_s:
            return Health.CPU_STARVED
        return Health.of_tracking(quality)

    def check(self, now: float, capture: object, tracking: object) -> Health | Fault | None:
        """A Fault, the state when no frame was tracked for no_frames_s, or None."""
        for thread in (capture, tracking):  # a configuration error ends the service itself
            if not thread.is_alive() and thread.error is not None \
                    and not isinstance(thread.error, InputError):
                error = thread.error
                return Fault(Health.FAILED, f"the {thread.name} thread died "
                                            f"({type(error).__name__}: {error})")
        busy = capture.busy
        if busy is not None and now - busy[1] > self.stall_timeout_s:
            return Fault(Health.CAMERA_BLOCKED,
                         f"camera {capture.source.name}: {busy[0]} has not returned for "
                         f"{now - busy[1]:.0f} s (the device does not answer)")
        hung = tracking.hung_for(now)
        if hung is not None:
            return Fault(Health.FAILED, f"the tracker has been on one frame for {hung:.0f} s")
        if self.last_frame_t is None or now - self.last_frame_t <= self.no_frames_s:
            return None
        if self._recent(now, capture.last_frame_t):
            return Health.CPU_STARVED  # the camera delivers; tracking does not keep up
        return Health.BAD_FRAMES if self._recent(now, capture.last_read_t) else Health.NO_CAMERA

    def _recent(self, now: float, t: float | None) -> bool:
        return t is not None and now - t <= self.no_frames_s
