"""What the autopilot parameter checks share: findings, the context they judge in, the wire
encoding of parameter values and which parameters need a reboot.

The rules themselves are in ardupilot_params.py and px4_params.py beside this module, the
stream groups and their rate parameters in stream_groups.py. They follow
docs/autopilot-interface.md and the autopilots' sources, and judge the parameter names the
autopilot really has (older and newer ArduPilot names both).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum

from pymavlink.dialects.v20 import common as mavlink2

INT32 = mavlink2.MAV_PARAM_TYPE_INT32
VISUAL_ODOMETRY_CHECK_BIT = 1 << 18  # ARMING_CHECK / ARMING_SKIPCHK bit (AP_Arming.cpp)
ARDUPILOT_POS_NOISE_MIN = 0.1  # VISO_POS_M_NSE: the lowest value ArduPilot documents
DELAY_TOLERANCE_MS = 10
# names whose change takes effect only after a reboot (@RebootRequired, or read at EKF start)
ARDUPILOT_REBOOT = ("VISO_TYPE", "VISO_DELAY_MS", "GPS_TYPE", "GPS1_TYPE", "EK3_ENABLE",
                    "AHRS_EKF_TYPE", "SERIAL", "MAV", "SR")
PX4_REBOOT = ("EKF2_", "MAV_")


def wire_value(flavour: str, value: float, param_type: int) -> float:
    """The float a PARAM_VALUE carries: ArduPilot casts, PX4 copies an INT32's bytes."""
    if flavour == "px4" and param_type == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def from_wire(flavour: str, value: float, param_type: int) -> float:
    """The parameter's number from a PARAM_VALUE float (inverse of wire_value)."""
    if flavour == "px4" and param_type == INT32:
        return float(struct.unpack("<i", struct.pack("<f", value))[0])
    return float(value)


def needs_reboot(flavour: str, name: str) -> bool:
    """Whether a changed parameter takes effect only after the autopilot reboots."""
    prefixes = ARDUPILOT_REBOOT if flavour == "ardupilot" else PX4_REBOOT
    return name.startswith(prefixes)


class Severity(IntEnum):
    """ERROR: a flight would not work or not be safe; WARNING: it works, worse than it could;
    NOTE: for the user to know, nothing to change."""

    ERROR = 0
    WARNING = 1
    NOTE = 2


@dataclass(frozen=True)
class Finding:
    """One thing check-autopilot says. `set_to` is what --apply writes to parameter `name`."""

    severity: Severity
    name: str
    value: float | None
    message: str
    set_to: float | None = None
    is_param: bool = True

    def __str__(self) -> str:
        head = f"{self.severity.name:7} {self.name}"
        if self.is_param:
            head += " (not on this autopilot)" if self.value is None else f" = {self.value:g}"
        if self.set_to is not None:
            head += f": set {self.set_to:g}"
        return f"{head}: {self.message}"


@dataclass(frozen=True)
class CheckContext:
    """What the rules need besides the parameters: the service's settings and what was
    measured on the link. None: not known."""

    output: str = "odometry"
    vision_rate_hz: float = 30.0  # vision messages per second: the camera's rate, at most 50
    fusion: bool = True
    good_std_m: float = 0.05  # position std the service sends when tracking well
    delay_ms: float | None = None  # the delay parameter's right value, measured
    delay_basis: str = ""
    gps_present: bool | None = None
    origin_enabled: bool | None = None


def first_name(p: dict[str, float], *names: str) -> str:
    """The first of `names` the autopilot has (newer names first), else the first."""
    return next((n for n in names if n in p), names[0])


def delay_finding(name: str, p: dict[str, float], ctx: CheckContext,
                  limit: float) -> Finding | None:
    """The delay parameter against the latency measured on this link."""
    if name not in p:
        return None
    if ctx.delay_ms is None:
        return Finding(Severity.NOTE, name, p[name], "not checked: the latency was not "
                       "measured (give --config with the camera, or --latency-ms)")
    wanted = min(limit, max(0, round(ctx.delay_ms)))
    measured = f"the delay measured on this link is {ctx.delay_ms:.0f} ms ({ctx.delay_basis})"
    if abs(p[name] - wanted) <= DELAY_TOLERANCE_MS:
        return Finding(Severity.NOTE, name, p[name], f"right within {DELAY_TOLERANCE_MS} ms: "
                       + measured)
    return Finding(Severity.WARNING, name, p[name], measured, wanted)


def finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)
