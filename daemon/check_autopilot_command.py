"""`sdvl check-autopilot --link URL`: is the autopilot set up to use our vision messages?

Waits for the autopilot's HEARTBEAT, tells ArduPilot from PX4, reads the parameters that matter
(VISO_*, EK3_SRC1_*, EKF2_EV_*, ...) and prints what is wrong and what to set. Exit 0 when
nothing is wrong, 1 when something is, 2 when no autopilot answers.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time

from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_params import check_parameters, from_wire, parameter_names
from daemon.autopilot_watch import AutopilotWatch
from daemon.config import OUTPUTS, load_config
from daemon.link import open_link
from daemon.mavlink_codec import MavlinkCodec
from sdvl.errors import InputError

PARAM_TRIES = 3
PARAM_WAIT_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl check-autopilot`."""
    parser.add_argument("--link", required=False, default=None,
                        help="autopilot link URL (udpout:HOST:PORT, udpin:ADDR:PORT, "
                             "tcp:HOST:PORT, serial:/dev/ttyX:BAUD); default: the config's")
    parser.add_argument("--config", default=None, help="service config (link and output type)")
    parser.add_argument("--output", choices=OUTPUTS, default=None,
                        help="vision message type the service sends (default: the config's, "
                             "else odometry)")
    parser.add_argument("--latency-ms", type=float, default=None,
                        help="measured capture-to-send latency (sdvl bench-latency) to check "
                             "VISO_DELAY_MS / EKF2_EV_DELAY against")
    parser.add_argument("--timeout", type=float, default=5.0,
                        help="seconds to wait for the autopilot's heartbeat (default 5)")


class ParamReader:
    """Heartbeat wait and PARAM_REQUEST_READ/PARAM_VALUE over one link."""

    def __init__(self, url: str):
        self.watch = AutopilotWatch(timeout_s=5.0)
        self.values: dict[str, tuple[float, int]] = {}
        self.heard = asyncio.Event()
        self.codec = MavlinkCodec(255, mavlink2.MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY,
                                  lambda b: self.link.write(b), self._on_message)
        self.link = open_link(url, self.codec.feed)

    def _on_message(self, msg: object) -> None:
        if self.watch.on_message(msg, time.monotonic()):
            self.heard.set()
        if msg.get_type() == "PARAM_VALUE":
            self.values[msg.param_id] = (msg.param_value, msg.param_type)

    async def wait_autopilot(self, timeout: float) -> None:
        """Send our heartbeat (a udpout peer needs it) until the autopilot's arrives."""
        deadline = time.monotonic() + timeout
        while not self.heard.is_set() and time.monotonic() < deadline:
            self.codec.send(self.codec.mav.heartbeat_encode(
                mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.heard.wait(), 0.5)
        if not self.heard.is_set():
            raise InputError(f"no autopilot heartbeat on {self.link.spec} within {timeout:g} s:"
                             " check the link URL, baud rate and that the port speaks MAVLink")

    async def read(self, names: tuple[str, ...]) -> dict[str, float | None]:
        """Each parameter's value; None for those the autopilot never sent."""
        target = (self.watch.system_id, self.watch.component_id)
        for _ in range(PARAM_TRIES):
            missing = [n for n in names if n not in self.values]
            if not missing:
                break
            for name in missing:
                self.codec.send(self.codec.mav.param_request_read_encode(*target, name.encode(),
                                                                         -1))
            await asyncio.sleep(PARAM_WAIT_S)
        flavour = self.watch.flavour
        return {n: (from_wire(flavour, *self.values[n]) if n in self.values else None)
                for n in names}


async def check(url: str, output: str, latency_ms: float | None, timeout: float) -> int:
    """Connect, read, print; the exit code."""
    reader = ParamReader(url)
    reader.link.start()
    try:
        await reader.wait_autopilot(timeout)
        flavour = reader.watch.flavour
        print(f"autopilot: {flavour} (system {reader.watch.system_id}) on {reader.link.spec}")
        if flavour == "unknown":
            print("not ArduPilot or PX4: nothing to check")
            return 1
        params = await reader.read(parameter_names(flavour))
    finally:
        await reader.link.close()
    findings = check_parameters(flavour, params, output, latency_ms)
    if reader.codec.mavlink1_seen:
        print("ERROR   link speaks MAVLink 1: set the autopilot port to MAVLink 2 "
              "(ArduPilot SERIALx_PROTOCOL=2), or quality and reset_counter are lost")
    for name, value in params.items():
        print(f"  {name:18} {'missing' if value is None else f'{value:g}'}")
    for finding in findings:
        print(finding)
    if not findings and not reader.codec.mavlink1_seen:
        print("OK: the autopilot is set up for vision")
        return 0
    return 1


def run(args: argparse.Namespace) -> int:
    """Entry point of `sdvl check-autopilot`."""
    cfg = load_config(args.config) if args.config else None
    url = args.link or (cfg.mavlink.link if cfg else None)
    if url is None:
        raise InputError("give --link URL or --config FILE")
    output = args.output or (cfg.mavlink.output if cfg else "odometry")
    return asyncio.run(check(url, output, args.latency_ms, args.timeout))
