"""What `sdvl check-autopilot` learns on the companion's port by listening and asking.

One Session holds the link: it waits for the autopilot's heartbeat, reads every parameter
(param_client.py), listens to what the port streams unasked, asks for the streams as the
service does (streams.py) and measures what then arrives, times TIMESYNC round trips, asks
whether a GPS is connected (GPS_RAW_INT fix type through MAV_CMD_REQUEST_MESSAGE), has the
autopilot run its pre-arm checks (MAV_CMD_RUN_PREARM_CHECKS; ArduPilot and PX4 answer with
STATUSTEXT failures) and notes whether its frames are still MAVLink 1 after ours (MAVLink 2)
reached it (ArduPilot starts a MAVLink 2 port in MAVLink 1 and switches when it hears 2).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_watch import AutopilotWatch
from daemon.link import open_link
from daemon.mavlink_codec import MAVLINK1_MAGIC, MavlinkCodec
from daemon.param_client import ParamClient
from daemon.stream_groups import needs_for
from daemon.streams import StreamKeeper, StreamStatus

SYSTEM_ID, COMPONENT_ID = 255, mavlink2.MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
LISTEN_S = 3.0  # what the port streams before anything is asked
ASK_LIMIT_S = 20.0
PREARM_WAIT_S = 2.0
TIMESYNC_PINGS = 10
V1_GRACE_S = 1.5  # after our first frame, time for the autopilot to switch to MAVLink 2
MAV_CMD_RUN_PREARM_CHECKS = 401
REBOOT_AUTOPILOT = 1


class NoAutopilotError(Exception):
    """No autopilot heartbeat came on the link."""


@dataclass
class Probe:
    """Everything heard and measured on the link."""

    flavour: str
    system_id: int
    link: str
    usb: bool
    baud: int  # 0: not a serial link
    params: dict[str, float]
    params_complete: bool
    mavlink1: bool
    unasked: dict[str, float]  # need kind -> Hz before anything was asked
    streams: list[StreamStatus]
    rtt_s: list[float]
    gps_fix_type: int | None
    prearm: list[str] | None  # None: the autopilot did not run them on request


class Session:
    """One link to the autopilot and what check-autopilot sends and hears on it."""

    def __init__(self, url: str):
        self.watch = AutopilotWatch(timeout_s=5.0)
        self.codec = MavlinkCodec(SYSTEM_ID, COMPONENT_ID, lambda b: self.link.write(b),
                                  self._on_message)
        self.link = open_link(url, self.codec.feed)
        self.params = ParamClient(self.codec, self.target, lambda: self.watch.flavour)
        self.keeper = StreamKeeper(self.codec, self.watch, self.link.spec.usb)
        self.heard = asyncio.Event()
        self.texts: list[tuple[float, str]] = []
        self.acks: dict[int, int] = {}
        self.rtt_s: list[float] = []
        self.gps_fix_type: int | None = None
        self.mavlink1_late = False
        self._first_sent: float | None = None
        self._pings: set[int] = set()
        self._beats: asyncio.Task | None = None

    def target(self) -> tuple[int, int]:
        return self.watch.system_id, self.watch.component_id

    async def __aenter__(self) -> Session:
        self.link.start()
        self._beats = asyncio.get_running_loop().create_task(self._heartbeats())
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._beats.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._beats
        await self.link.close()

    def _on_message(self, msg: object) -> None:
        now = time.monotonic()
        if self.watch.on_message(msg, now):
            self.heard.set()
        if self.watch.system_id is None or msg.get_srcSystem() != self.watch.system_id:
            return
        self.keeper.on_message(msg, now)
        self.params.on_message(msg)
        late = self._first_sent is not None and now - self._first_sent > V1_GRACE_S
        self.mavlink1_late |= late and msg.get_msgbuf()[0] == MAVLINK1_MAGIC
        kind = msg.get_type()
        if kind == "STATUSTEXT":
            self.texts.append((now, msg.text))
        elif kind == "COMMAND_ACK":
            self.acks[msg.command] = msg.result
        elif kind == "TIMESYNC" and msg.tc1 != 0 and msg.ts1 in self._pings:
            self.rtt_s.append((time.monotonic_ns() - msg.ts1) * 1e-9)
        elif kind == "GPS_RAW_INT":
            self.gps_fix_type = msg.fix_type

    async def _heartbeats(self) -> None:
        """Our HEARTBEAT at 1 Hz (a udpout peer learns our address from it; ArduPilot switches
        the port to MAVLink 2 when it hears MAVLink 2)."""
        while True:
            if self.codec.send(self.codec.mav.heartbeat_encode(
                    mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID,
                    0, 0, 0)) and self._first_sent is None:
                self._first_sent = time.monotonic()
            await asyncio.sleep(1.0 if self.heard.is_set() else 0.3)

    async def wait_autopilot(self, timeout_s: float) -> None:
        """Until the autopilot's heartbeat; NoAutopilotError saying what to check if none."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.heard.wait(), timeout_s)
        if self.heard.is_set():
            return
        if self.link.last_error is not None:
            raise NoAutopilotError(
                f"cannot open {self.link.spec}: {self.link.last_error} (is sdvl-companion "
                "running? stop it first: both use the port)")
        raise NoAutopilotError(
            f"no autopilot heartbeat on {self.link.spec} within {timeout_s:g} s: check the link "
            "URL (udpin: when the autopilot sends to us), the baud rate, and that the autopilot "
            "runs MAVLink on that port (ArduPilot SERIALn_PROTOCOL = 2, PX4 MAV_n_CONFIG = that "
            "TELEM port, then reboot it)")

    def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG to the autopilot (params 1..7, the rest 0)."""
        values = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        self.codec.send(self.codec.mav.command_long_encode(*self.target(), command, 0, *values))

    async def probe(self, param_timeout_s: float) -> Probe:
        """Read, listen, ask and measure (about 10 s plus the parameter download)."""
        params = asyncio.create_task(self.params.fetch_all(param_timeout_s))
        self.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT)
        await self._ping(LISTEN_S)
        now = time.monotonic()
        needs = needs_for(self.watch.flavour)
        unasked = {n.kind: self.keeper.rate(n.accepts, now) for n in needs}
        await self._ask_streams()
        streams = list(self.keeper.statuses.values())
        self.keeper.release()
        prearm = await self._prearm()
        values = await params
        return Probe(self.watch.flavour, self.watch.system_id, str(self.link.spec),
                     self.link.spec.usb, self.link.spec.baud, values, self.params.complete,
                     self.mavlink1_late,
                     unasked, streams, list(self.rtt_s), self.gps_fix_type, prearm)

    async def _ping(self, seconds: float) -> None:
        """TIMESYNC requests (tc1 = 0) spread over `seconds`; answers give round trips."""
        for _ in range(TIMESYNC_PINGS):
            stamp = time.monotonic_ns()
            self._pings.add(stamp)
            self.codec.send(self.codec.mav.timesync_encode(0, stamp))
            await asyncio.sleep(seconds / TIMESYNC_PINGS)

    async def _ask_streams(self) -> None:
        """Ask as the service asks, and give the streams the time the service gives them."""
        deadline = time.monotonic() + ASK_LIMIT_S
        self.keeper.restart(time.monotonic())
        while not self.keeper.settled(time.monotonic()) and time.monotonic() < deadline:
            self.keeper.tick(time.monotonic())
            await asyncio.sleep(0.05)
        self.keeper.tick(time.monotonic())

    async def _prearm(self) -> list[str] | None:
        """The autopilot's pre-arm failures, run on request, with any it sent on its own while
        we listened; None when it ran none and said none."""
        self.command(MAV_CMD_RUN_PREARM_CHECKS)
        await asyncio.sleep(PREARM_WAIT_S)
        texts = list(dict.fromkeys(text for _, text in self.texts if is_prearm_text(text)))
        ran = self.acks.get(MAV_CMD_RUN_PREARM_CHECKS) == mavlink2.MAV_RESULT_ACCEPTED
        return texts if ran or texts else None

    async def reboot(self, timeout_s: float) -> bool:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN; True once the autopilot accepted it."""
        self.acks.pop(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, None)
        self.command(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, REBOOT_AUTOPILOT)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            result = self.acks.get(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN)
            if result is not None:
                return result == mavlink2.MAV_RESULT_ACCEPTED
            await asyncio.sleep(0.05)
        return False


def is_prearm_text(text: str) -> bool:
    """A pre-arm failure as ArduPilot ('PreArm: ...') or PX4 ('Preflight Fail: ...') says it."""
    return text.startswith(("PreArm:", "Preflight Fail", "Arming denied"))
