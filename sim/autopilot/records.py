"""What the simulated autopilot records for tests and the replay's report: every STATUSTEXT it
sent, its events (boots, external nav started/stopped, position and height resets, arming,
modes, failsafes) and the history of its own position estimate. Plain dataclasses, so a record
crosses a process boundary."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum, IntEnum

import numpy as np


class Severity(IntEnum):
    """MAV_SEVERITY."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


class EventKind(Enum):
    """Things that happened inside the autopilot."""

    BOOT = "boot"
    EXTNAV_STARTED = "external nav started"
    EXTNAV_STOPPED = "external nav stopped"
    POSITION_RESET = "position reset"
    HEIGHT_RESET = "height reset"
    VISION_IGNORED = "vision ignored after reset"
    VISION_REALIGNED = "vision re-aligned"
    ARMED = "armed"
    DISARMED = "disarmed"
    ARMING_REFUSED = "arming refused"
    MODE = "mode"
    MODE_REFUSED = "mode refused"
    FAILSAFE = "failsafe"


@dataclass(frozen=True)
class StatusText:
    t: float
    severity: Severity
    text: str


@dataclass(frozen=True)
class Event:
    """`detail` says what, e.g. the mode name or the size of a reset in metres."""

    t: float
    kind: EventKind
    detail: str = ""
    value: float = 0.0


@dataclass(frozen=True)
class EstimateSample:
    """The autopilot's own estimate (NED, from its origin) at time t."""

    t: float
    position: np.ndarray
    velocity: np.ndarray
    using_vision: bool


@dataclass
class AutopilotRecord:
    statustexts: list[StatusText] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    estimates: list[EstimateSample] = field(default_factory=list)

    def texts(self) -> list[str]:
        return [s.text for s in self.statustexts]

    def of(self, kind: EventKind) -> list[Event]:
        return [e for e in self.events if e.kind is kind]

    def first(self, kind: EventKind) -> Event | None:
        found = self.of(kind)
        return found[0] if found else None

