"""The one autopilot the service listens to: binding, heartbeat watchdog, reboots.

Messages are taken only from the autopilot the service is bound to: the system and component in
the config, or else the first autopilot HEARTBEAT heard (a GCS or another companion is not an
autopilot). Anything from another system or component is ignored and counted, logged once per
source, so a second vehicle or a replayed log on the same radio cannot steer the fusion. A
message whose boot stamp is off the autopilot's clock (boot_clock.py) is ignored as well; a
sustained restart of that clock is a reboot.
"""

from __future__ import annotations

import enum
import logging
from collections import Counter
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from daemon.boot_clock import BootClock, Stamp, boot_seconds

log = logging.getLogger("sdvl.autopilot")
NOT_AUTOPILOTS = (mavlink2.MAV_TYPE_GCS, mavlink2.MAV_TYPE_ONBOARD_CONTROLLER)


class Event(enum.StrEnum):
    """What happened to the bound autopilot."""

    CONNECTED = "connected"
    LOST = "lost"
    RECONNECTED = "reconnected"  # heartbeat back after a loss
    REBOOTED = "rebooted"
    CLOCK_JUMPED = "clock jumped"


class Ignored(enum.StrEnum):
    """Why a message did not reach the estimator."""

    UNBOUND = "before the autopilot's first HEARTBEAT"
    OTHER_SOURCE = "from another system or component"
    OFF_CLOCK = "stamp off the autopilot's clock"


@dataclass
class Verdict:
    """One message: whether it is the bound autopilot's and what it caused."""

    accepted: bool
    events: list[Event] = field(default_factory=list)


def is_autopilot_heartbeat(msg: object) -> bool:
    """A HEARTBEAT from a flight controller (not a GCS, companion or peripheral)."""
    return (msg.get_type() == "HEARTBEAT" and msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID
            and msg.type not in NOT_AUTOPILOTS)


class AutopilotWatch:
    """Feed every received message to `receive`; call `check` periodically for link loss."""

    def __init__(self, timeout_s: float, system_id: int = 0, component_id: int = 0,
                 own: tuple[int, int] | None = None):
        self.timeout_s = timeout_s
        self.wanted = (system_id, component_id)  # 0: whichever the first heartbeat says
        self.own = own  # our own (system, component): an echo of it is not worth a log line
        self.system_id: int | None = None
        self.component_id: int | None = None
        self.autopilot: int | None = None  # MAV_AUTOPILOT_ARDUPILOTMEGA (3), _PX4 (12), ...
        self.last_heartbeat: float | None = None
        self.alive = False
        self.clock = BootClock()
        self.reboots = 0
        self.losses = 0
        self.ignored: Counter[Ignored] = Counter()
        self.ignored_sources: Counter[tuple[int, int]] = Counter()

    @property
    def bound(self) -> bool:
        return self.system_id is not None

    @property
    def flavour(self) -> str:
        """'ardupilot', 'px4' or 'unknown'."""
        return {mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot",
                mavlink2.MAV_AUTOPILOT_PX4: "px4"}.get(self.autopilot, "unknown")

    def receive(self, msg: object, now: float) -> Verdict:
        """Bind on the first matching autopilot HEARTBEAT; accept only the bound autopilot's
        messages whose stamps are on its clock."""
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if not self.bound and is_autopilot_heartbeat(msg) and self._wanted(source):
            self._bind(msg, source)
        if source != (self.system_id, self.component_id):
            self._ignore(Ignored.OTHER_SOURCE if self.bound else Ignored.UNBOUND, msg, source)
            return Verdict(False)
        verdict = Verdict(True)
        if is_autopilot_heartbeat(msg):
            self.autopilot = msg.autopilot
            if not self.alive:
                verdict.events.append(Event.RECONNECTED if self.last_heartbeat is not None
                                      else Event.CONNECTED)
            self.alive, self.last_heartbeat = True, now
        boot = boot_seconds(msg)
        stamp = Stamp.NONE if boot is None else self.clock.observe(boot, now)
        if stamp is Stamp.OFF_CLOCK:
            self._ignore(Ignored.OFF_CLOCK, msg, source)
            verdict.accepted = False
        elif stamp is Stamp.REBOOTED:
            self.reboots += 1
            verdict.events.append(Event.REBOOTED)
        elif stamp is Stamp.JUMPED:
            verdict.events.append(Event.CLOCK_JUMPED)
        return verdict

    def on_message(self, msg: object, now: float) -> list[Event]:
        """The events one message caused (for callers that need no verdict)."""
        return self.receive(msg, now).events

    def check(self, now: float) -> list[Event]:
        """[LOST] once when no heartbeat came for timeout_s."""
        if self.alive and now - self.last_heartbeat > self.timeout_s:
            self.alive = False
            self.losses += 1
            return [Event.LOST]
        return []

    def _wanted(self, source: tuple[int, int]) -> bool:
        return all(want in (0, got) for want, got in zip(self.wanted, source, strict=True))

    def _bind(self, msg: object, source: tuple[int, int]) -> None:
        self.system_id, self.component_id = source
        self.autopilot = msg.autopilot
        how = ("as configured" if self.wanted[0] else "the first autopilot heard; "
               "mavlink.autopilot_system_id/_component_id choose another")
        log.info("bound to autopilot system %d component %d (%s), %s", *source, self.flavour,
                 how)

    def _ignore(self, why: Ignored, msg: object, source: tuple[int, int]) -> None:
        self.ignored[why] += 1
        if why is Ignored.OTHER_SOURCE:
            self.ignored_sources[source] += 1
            if self.ignored_sources[source] == 1 and source != self.own:
                log.warning("ignoring MAVLink system %d component %d (first: %s): only the "
                            "autopilot system %d component %d is listened to", *source,
                            msg.get_type(), self.system_id, self.component_id)
        elif why is Ignored.OFF_CLOCK and self.ignored[why] == 1:
            log.warning("ignoring %s stamped %.3f s: off the autopilot's boot clock (counted "
                        "from now on, logged once)", msg.get_type(), boot_seconds(msg))
