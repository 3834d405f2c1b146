"""Make the autopilot stream what the estimator needs, check that it does, say what to set.

On the first heartbeat, after a reboot or a lost link, and when a stream that flowed stops, the
keeper asks for each message of stream_groups.needs_for(flavour) with
MAV_CMD_SET_MESSAGE_INTERVAL, one at a time. Refused or unanswered: ArduPilot is asked for the
message's stream group with REQUEST_DATA_STREAM; PX4 is left to its MAV_n_MODE streams. Once the
answers are in and the streams had time to start, each is measured over the last seconds; one
below its usable rate is reported in one log line and one STATUSTEXT naming the message and the
parameter on this autopilot that would send it (read from the autopilot with
PARAM_REQUEST_READ). A missing rangefinder is only logged (many vehicles have none).
"""

from __future__ import annotations

import logging
import math
import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_params import from_wire
from daemon.statustext import MAX_TEXT, PREFIX
from daemon.stream_groups import (
    ARDUPILOT_GROUPS,
    DATA_STREAM_IDS,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    NEEDS,
    PX4_INSTANCES,
    SERIAL_PORTS,
    Need,
    Presence,
    generic_hint,
    needs_for,
    stream_hints,
)

log = logging.getLogger("sdvl.streams")
ACK_TIMEOUT_S = 1.0  # ArduPilot and PX4 answer a command within a few loop periods
ASK_TRIES = 2
SETTLE_S = 3.0  # streams get this long after the last request before they are judged
WINDOW_S = 2.0  # arrival rates are counted over this window
SILENT_S = 3.0  # a stream that flowed and stops this long: ask again (a reboot not seen)
REASK_MIN_S = 10.0
# ticks this far apart: the loop was held up (a starved CPU) and read the link no more often, so
# the rates it measured are ours, not the autopilot's; they are not judged for WINDOW_S after
LOOP_HELD_S = 0.5
HELD_SAY_EVERY_S = 60.0
# a stream said to be below its floor is back only this far above it: counted over WINDOW_S,
# one at its floor comes and goes by a message a window (RAW_IMU at 19.5-20 Hz against 20 was
# said 104 times in an hour)
RECOVERED = 1.2
REPEAT_S = 60.0  # and a need is said at most this often, however its rate comes and goes
PARAM_WAIT_S = 1.5
TRACKED = {name for needs in NEEDS.values() for need in needs for name in need.accepts}
HINT_PARAMS = {"ardupilot": ("MAV1_EXTRA1", "SR0_EXTRA1",
                             *(f"SERIAL{x}_PROTOCOL" for x in SERIAL_PORTS)),
               "px4": tuple(f"MAV_{n}_{p}" for n in PX4_INSTANCES for p in ("MODE", "CONFIG"))}


class Answer(Enum):
    """What the autopilot said to MAV_CMD_SET_MESSAGE_INTERVAL."""

    PENDING = "not answered yet"
    ACCEPTED = "accepted"
    REFUSED = "refused"
    NO_ANSWER = "no answer"


@dataclass
class StreamStatus:
    """One need: how it was asked for and the rate it arrives at."""

    need: Need
    answer: Answer = Answer.PENDING
    method: str = "SET_MESSAGE_INTERVAL"  # how it was asked for in the end
    rate_hz: float = 0.0

    @property
    def usable(self) -> bool:
        return self.rate_hz >= self.need.min_hz


class StreamKeeper:
    """Fed every message (`on_message`) and ticked by the loop (`tick`); `report(text,
    severity)` sends a STATUSTEXT (None: judge nothing, as check-autopilot does)."""

    def __init__(self, codec: object, watch: object, usb: bool,
                 report: Callable[[str, int], None] | None = None):
        self.codec = codec
        self.watch = watch
        self.usb = usb
        self.report = report
        self.statuses: dict[str, StreamStatus] = {}
        self.params: dict[str, float] = {}
        self.arrivals: dict[str, deque] = {}
        self.last_arrival: dict[str, float] = {}
        self.restarts = 0
        self._queue: list[Need] = []
        self._asking: tuple[Need, float, int] | None = None
        self._asked_all_at: float | None = None
        self._epoch_at: float | None = None
        self._seen: tuple[int, int] | None = None
        self._reported: set[str] = set()  # needs said to be missing, not back since
        self._said_at: dict[str, float] = {}
        self._params_asked_at: float | None = None
        self._last_tick: float | None = None
        self._held_until = -math.inf  # rates not judged before then (the loop was held up)
        self._held_said = -math.inf

    # --- input -----------------------------------------------------------------------------

    def on_message(self, msg: object, now: float) -> None:
        """Count stream arrivals; take command answers and parameter values."""
        if self.watch.system_id is None or msg.get_srcSystem() != self.watch.system_id:
            return
        name = msg.get_type()
        if name == "COMMAND_ACK":
            if msg.command == MAV_CMD_SET_MESSAGE_INTERVAL and self._asking is not None:
                accepted = msg.result == mavlink2.MAV_RESULT_ACCEPTED
                self._answered(Answer.ACCEPTED if accepted else Answer.REFUSED, now)
        elif name == "PARAM_VALUE":
            self.params[msg.param_id] = from_wire(self.watch.flavour, msg.param_value,
                                                  msg.param_type)
        elif name in TRACKED:
            times = self.arrivals.setdefault(name, deque())
            times.append(now)
            while now - times[0] > WINDOW_S:  # a stream no need asks for is never rated
                times.popleft()
            self.last_arrival[name] = now

    def rate(self, names: tuple[str, ...], now: float) -> float:
        """Messages per second of the fastest of `names` over the last WINDOW_S (older
        arrivals are dropped as they age out, so this stays cheap in the loop)."""
        best = 0
        for name in names:
            times = self.arrivals.get(name)
            while times and now - times[0] > WINDOW_S:
                times.popleft()
            best = max(best, len(times or ()))
        return best / WINDOW_S

    # --- the loop ----------------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """Ask, re-ask after a reboot or a silence, and (with `report`) judge the streams."""
        held = self._held(now)
        if not self.watch.alive or self.watch.system_id is None:
            return
        if self._must_restart(now):
            self.restart(now)
        self._ask_next(now)
        for status in self.statuses.values():
            status.rate_hz = self.rate(status.need.accepts, now)
        if self.report is not None and self.settled(now) and not held:
            self._judge(now)

    def _held(self, now: float) -> bool:
        """Whether the loop was held up within the rate window (see LOOP_HELD_S); said at most
        every HELD_SAY_EVERY_S."""
        gap = now - self._last_tick if self._last_tick is not None else 0.0
        self._last_tick = now
        if gap > LOOP_HELD_S:
            self._held_until = now + WINDOW_S
            if now - self._held_said >= HELD_SAY_EVERY_S:
                self._held_said = now
                log.warning("the service's loop was held up %.1f s (CPU overloaded): stream "
                            "rates are not judged until it keeps up", gap)
        return now < self._held_until

    def restart(self, now: float) -> None:
        """Ask for every need again (on connect, after a reboot or a lost link). A stream
        already reported missing is not reported again until it has come back."""
        self.restarts += 1
        self._epoch_at, self._seen = now, (self.watch.reboots, self.watch.losses)
        needs = needs_for(self.watch.flavour)
        self.statuses = {n.kind: StreamStatus(n) for n in needs}
        self._queue, self._asking, self._asked_all_at = list(needs), None, None
        log.info("asking the autopilot (%s) for %s", self.watch.flavour,
                 ", ".join(f"{n.request} at {n.rate_hz:g} Hz" for n in needs))

    def settled(self, now: float) -> bool:
        """Every need was asked for and has had SETTLE_S to start arriving."""
        return self._asked_all_at is not None and now - self._asked_all_at >= SETTLE_S

    def release(self) -> None:
        """Put the asked messages back to the autopilot's default rates (interval 0)."""
        for status in self.statuses.values():
            self._send_interval(status.need, 0)

    def _must_restart(self, now: float) -> bool:
        if self._epoch_at is None or self._seen != (self.watch.reboots, self.watch.losses):
            return True
        if now - self._epoch_at < REASK_MIN_S:
            return False
        return any(s.need.presence == Presence.ALWAYS and not s.usable
                   and self._flowed_then_stopped(s.need, now) for s in self.statuses.values())

    def _flowed_then_stopped(self, need: Need, now: float) -> bool:
        last = max((self.last_arrival[n] for n in need.accepts if n in self.last_arrival),
                   default=None)
        return last is not None and now - last > SILENT_S

    # --- asking ------------------------------------------------------------------------------

    def _target(self) -> tuple[int, int]:
        return self.watch.system_id, self.watch.component_id

    def _send_interval(self, need: Need, interval_us: float) -> None:
        self.codec.send(self.codec.mav.command_long_encode(
            *self._target(), MAV_CMD_SET_MESSAGE_INTERVAL, 0, need.message_id, interval_us,
            0, 0, 0, 0, 0))

    def _ask_next(self, now: float) -> None:
        if self._asking is not None:
            need, sent_at, tries = self._asking
            if now - sent_at < ACK_TIMEOUT_S:
                return
            if tries < ASK_TRIES:
                self._send_interval(need, 1e6 / need.rate_hz)
                self._asking = (need, now, tries + 1)
                return
            self._answered(Answer.NO_ANSWER, now)
        if self._queue:
            need = self._queue.pop(0)
            self._send_interval(need, 1e6 / need.rate_hz)
            self._asking = (need, now, 1)

    def _answered(self, answer: Answer, now: float) -> None:
        need = self._asking[0]
        status = self.statuses[need.kind]
        status.answer = answer
        if answer != Answer.ACCEPTED:
            status.method = self._fallback(need)
        self._asking = None
        if not self._queue:
            self._asked_all_at = now

    def _fallback(self, need: Need) -> str:
        """ArduPilot: ask for the message's stream group; PX4: its MAV_n_MODE streams."""
        if self.watch.flavour != "ardupilot":
            return "left to the autopilot's own streams (MAV_n_MODE)"
        group = ARDUPILOT_GROUPS[need.request]
        self.codec.send(self.codec.mav.request_data_stream_encode(
            *self._target(), DATA_STREAM_IDS[group], round(need.rate_hz), 1))
        return f"REQUEST_DATA_STREAM {group}"

    # --- judging -----------------------------------------------------------------------------

    def _judge(self, now: float) -> None:
        """Say each need below its floor once, again only after it was clearly back
        (RECOVERED) and REPEAT_S after it was last said."""
        for kind, status in self.statuses.items():
            if status.usable:
                if kind in self._reported and status.rate_hz >= RECOVERED * status.need.min_hz:
                    self._reported.discard(kind)
                    log.info("%s arrives again at %.0f Hz", status.need.request, status.rate_hz)
                continue
            if (kind in self._reported or status.need.presence == Presence.ESTIMATE
                    or now - self._said_at.get(kind, -math.inf) < REPEAT_S):
                continue
            if status.need.presence == Presence.SENSOR and status.rate_hz == 0:
                self._said(kind, now)
                log.info("no %s from the autopilot: no %s fitted (or not streamed); the scale "
                         "comes from the IMU and the barometer", status.need.request, kind)
                continue
            if self._hint_params_ready(now):
                self._said(kind, now)
                self._say_missing(status)

    def _said(self, kind: str, now: float) -> None:
        self._reported.add(kind)
        self._said_at[kind] = now

    def _hint_params_ready(self, now: float) -> bool:
        """Read the parameters that name the fix once, then wait PARAM_WAIT_S for them."""
        if self._params_asked_at is None:
            self._params_asked_at = now
            for name in HINT_PARAMS.get(self.watch.flavour, ()):
                self.codec.send(self.codec.mav.param_request_read_encode(
                    *self._target(), name.encode(), -1))
        return now - self._params_asked_at >= PARAM_WAIT_S

    def _say_missing(self, status: StreamStatus) -> None:
        need, flavour = status.need, self.watch.flavour
        hints = stream_hints(flavour, need, self.params, self.usb)
        fix = " or ".join(map(str, hints)) if hints else generic_hint(flavour, need)
        asked = f"asked for {need.rate_hz:g} Hz with SET_MESSAGE_INTERVAL: {status.answer.value}"
        if status.answer != Answer.ACCEPTED:
            asked += f", then {status.method}"
        log.warning("%s (%s) arrives at %.1f Hz, the service needs %g Hz (%s): set %s and reboot "
                    "the autopilot", need.request, need.kind, status.rate_hz, need.min_hz, asked,
                    fix)
        what = (f"no {need.request}" if status.rate_hz == 0
                else f"{need.request} {status.rate_hz:.0f}Hz")
        head = f"{what}: set "
        room = MAX_TEXT - len(PREFIX) - len(head)
        self.report(head + _short_fix(hints, fix, room), mavlink2.MAV_SEVERITY_WARNING)


def _short_fix(hints: list, fix: str, room: int) -> str:
    """The fix in a STATUSTEXT's room: the parameter with its value, the candidates, or their
    family (MAVn_EXTRA1) when they do not fit; the log line has the whole."""
    if len(hints) == 1:
        return f"{hints[0].name}={hints[0].value:g}"
    if not hints:
        return fix.split(" ")[0]
    names = " or ".join(h.name for h in hints)
    return names if len(names) <= room else re.sub(r"\d+", "n", hints[0].name, count=1)
