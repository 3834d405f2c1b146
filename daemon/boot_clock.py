"""The autopilot's boot clock as its messages show it: which stamps are on it, and when it
really restarted (a reboot) rather than one message carrying an odd stamp.

An autopilot stamps its messages with its time since boot (time_boot_ms; time_usec of the IMU
and altitude messages, hrt_absolute_time on PX4 and AP_HAL::micros64 on ArduPilot). That clock
only goes forward, and it cannot run ahead of our clock: a stamp is on it when it is no more than
BACKSTEP_S behind the newest stamp and no later than the least-delayed message says it can be
(the idea of ArduPilot's libraries/AP_RTC/JitterCorrection.cpp: the smallest arrival-minus-stamp
offset is the link's own delay). A stamp off the clock starts a second, candidate clock; the
candidate replaces the clock only when it is sustained (CONFIRM_S of its own time, CONFIRM_COUNT
messages) while nothing arrives on the old one: backwards it is a reboot, forwards a jump.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

BACKSTEP_S = 1.0  # stamps may come out of order by this much (PX4 stamps sensor samples)
AHEAD_S = 1.0  # and arrive this much earlier than the least-delayed message implies
EARLY_S = 0.05  # ... but only this much of it is believed (a link delay's jitter)
CONFIRM_S = 1.0  # a new clock must cover this much of its own time ...
CONFIRM_COUNT = 5  # ... in this many messages, with none on the old clock in between
OFFSET_RELAX = 1e-3  # s/s: the least-delay offset forgets (far above any crystal's drift)
BOOT_USEC_MESSAGES = ("HIGHRES_IMU", "RAW_IMU", "ALTITUDE")  # their time_usec is boot time


class Stamp(enum.Enum):
    """What one message's stamp says about the autopilot's clock."""

    NONE = "no boot stamp"
    ON_CLOCK = "on the clock"
    OFF_CLOCK = "off the clock"
    REBOOTED = "rebooted"
    JUMPED = "clock jumped"


def boot_seconds(msg: object) -> float | None:
    """The message's time since the autopilot's boot in seconds, if it carries one."""
    boot_ms = getattr(msg, "time_boot_ms", None)
    if boot_ms is not None:
        return boot_ms * 1e-3
    if msg.get_type() in BOOT_USEC_MESSAGES:
        return msg.time_usec * 1e-6
    return None


@dataclass
class _Track:
    """One clock hypothesis: its newest stamp, the least delay seen and how much supports it."""

    boot: float
    arrival: float
    offset: float  # smallest arrival - stamp, relaxed over time
    first_boot: float
    first_arrival: float
    count: int = 1

    @classmethod
    def start(cls, boot: float, arrival: float) -> _Track:
        return cls(boot, arrival, arrival - boot, boot, arrival)

    def latest(self, arrival: float) -> float:
        """The latest stamp a message arriving at `arrival` can carry on this clock."""
        return arrival - self.offset - OFFSET_RELAX * max(0.0, arrival - self.arrival)

    def fits(self, boot: float, arrival: float) -> bool:
        return self.boot - BACKSTEP_S <= boot <= self.latest(arrival) + AHEAD_S

    def add(self, boot: float, arrival: float) -> None:
        """Take a stamp on this clock. One ahead of the least-delay prediction moves it by at
        most EARLY_S: odd stamps within AHEAD_S must not walk the clock forward."""
        latest = self.latest(arrival)
        boot = min(boot, latest + EARLY_S)
        self.offset = arrival - max(latest, boot)  # the least delay, relaxed
        self.boot, self.arrival = max(self.boot, boot), max(self.arrival, arrival)
        self.count += 1

    @property
    def span(self) -> float:
        return self.boot - self.first_boot


class BootClock:
    """Feed every message's stamp with its arrival time on our clock (`observe`)."""

    def __init__(self) -> None:
        self._clock: _Track | None = None
        self._candidate: _Track | None = None
        self.off_clock = 0
        self.jump_s = 0.0  # of the last reboot or jump: new clock minus old, seconds

    def observe(self, boot: float, arrival: float) -> Stamp:
        """Classify one stamp (seconds since the autopilot's boot) that arrived at `arrival`."""
        clock = self._clock
        if clock is None:
            self._clock = _Track.start(boot, arrival)
            return Stamp.ON_CLOCK
        candidate = self._candidate
        on_candidate = candidate is not None and candidate.fits(boot, arrival)
        # a stamp behind the clock's newest that the candidate also explains is the candidate's
        # (a reboot soon after boot reaches the old clock's recent stamps again)
        if clock.fits(boot, arrival) and (boot >= clock.boot or not on_candidate):
            clock.add(boot, arrival)
            self._candidate = None
            return Stamp.ON_CLOCK
        if on_candidate:
            candidate.add(boot, arrival)
        else:
            candidate = self._candidate = _Track.start(boot, arrival)
        if clock.count < CONFIRM_COUNT and candidate.count > clock.count:
            self._clock, self._candidate = candidate, None  # the first stamps were the odd ones
            return Stamp.ON_CLOCK
        if candidate.span < CONFIRM_S or candidate.count < CONFIRM_COUNT:
            self.off_clock += 1
            return Stamp.OFF_CLOCK
        self._clock, self._candidate = candidate, None
        self.jump_s = candidate.first_boot - clock.latest(candidate.first_arrival)
        return Stamp.REBOOTED if self.jump_s < 0 else Stamp.JUMPED
