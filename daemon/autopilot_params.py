"""Which autopilot parameters a vision source needs, and what is wrong with the ones read back.

The rules follow docs/autopilot-interface.md (ArduPilot AP_VisualOdom + EKF3, PX4 EKF2 external
vision). Each finding names the parameter, what to set and why.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

INT32 = mavlink2.MAV_PARAM_TYPE_INT32
ARDUPILOT_NAMES = ("AHRS_EKF_TYPE", "EK3_ENABLE", "VISO_TYPE", "VISO_ORIENT", "VISO_SCALE",
                   "VISO_DELAY_MS", "VISO_QUAL_MIN", "VISO_POS_M_NSE", "VISO_YAW_M_NSE",
                   "EK3_SRC1_POSXY", "EK3_SRC1_VELXY", "EK3_SRC1_POSZ", "EK3_SRC1_VELZ",
                   "EK3_SRC1_YAW")
PX4_NAMES = ("EKF2_EV_CTRL", "EKF2_HGT_REF", "EKF2_EV_DELAY", "EKF2_EV_NOISE_MD", "EKF2_EV_QMIN",
             "EKF2_EVP_NOISE", "EKF2_EVA_NOISE")
DELAY_TOLERANCE_MS = 10


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


@dataclass(frozen=True)
class Finding:
    """One problem: `severity` is 'error' (vision will not work) or 'warning' (works badly)."""

    severity: str
    name: str
    value: float | None
    fix: str

    def __str__(self) -> str:
        shown = "missing" if self.value is None else f"{self.value:g}"
        return f"{self.severity.upper():7} {self.name} = {shown}: {self.fix}"


def parameter_names(flavour: str) -> tuple[str, ...]:
    """The parameters to read for 'ardupilot' or 'px4'."""
    return ARDUPILOT_NAMES if flavour == "ardupilot" else PX4_NAMES


def check_parameters(flavour: str, params: dict[str, float | None], output: str,
                     latency_ms: float | None = None) -> list[Finding]:
    """Findings for the parameters read back (None = the autopilot does not have it)."""
    rules = _ardupilot if flavour == "ardupilot" else _px4
    return rules(params, output, latency_ms)


def _ardupilot(p: dict, output: str, latency_ms: float | None) -> list[Finding]:
    out: list[Finding] = []

    def want(name: str, ok: bool, fix: str, severity: str = "error") -> None:
        if p.get(name) is None:
            out.append(Finding("error", name, None,
                               "not on this autopilot: firmware built without VisualOdom/EKF3?"))
        elif not ok:
            out.append(Finding(severity, name, p[name], fix))

    g = {k: (v if v is not None else float("nan")) for k, v in p.items()}
    want("AHRS_EKF_TYPE", g.get("AHRS_EKF_TYPE") == 3, "set 3: external navigation needs EKF3")
    want("EK3_ENABLE", g.get("EK3_ENABLE") == 1, "set 1 (reboot)")
    want("VISO_TYPE", g.get("VISO_TYPE") in (1, 2, 3),
         "set 3 (generic MAVLink odometry, re-aligns on resets) and reboot")
    want("VISO_ORIENT", g.get("VISO_ORIENT") == 0,
         "set 0: the companion already turns camera axes into body FRD", "warning")
    want("VISO_SCALE", g.get("VISO_SCALE") == 1,
         "set 1: scale is applied by the companion (mounting.scale); it would apply twice",
         "warning")
    if output == "vision_position":
        want("VISO_QUAL_MIN", g.get("VISO_QUAL_MIN", 0) <= 0,
             "set 0: VISION_POSITION_ESTIMATE has no quality (it counts as 0)")
    else:
        want("VISO_QUAL_MIN", g.get("VISO_QUAL_MIN", 0) >= 0,
             "set 0 or more, or samples marked failed are fused", "warning")
    want("EK3_SRC1_POSXY", g.get("EK3_SRC1_POSXY") == 6, "set 6 (ExternalNav)")
    want("EK3_SRC1_VELXY", g.get("EK3_SRC1_VELXY") in (0, 6), "set 6 (ExternalNav) or 0")
    want("EK3_SRC1_POSZ", g.get("EK3_SRC1_POSZ") in (1, 2, 6),
         "set 1 (Baro, usually safer) or 6 (ExternalNav)")
    want("EK3_SRC1_VELZ", g.get("EK3_SRC1_VELZ") in (0, 6), "set 6 (ExternalNav) or 0")
    want("EK3_SRC1_YAW", g.get("EK3_SRC1_YAW") in (1, 6),
         "set 6 (ExternalNav, no compass) or 1 (Compass, with VISO_TYPE 2/3 aligning yaw)")
    if g.get("EK3_SRC1_YAW") == 1 and g.get("VISO_TYPE") == 1:
        out.append(Finding("warning", "VISO_TYPE", 1,
                           "set 3: type 1 never aligns the vision yaw with the compass"))
    _delay(out, "VISO_DELAY_MS", p, latency_ms, 250)
    return out


def _px4(p: dict, output: str, latency_ms: float | None) -> list[Finding]:
    out: list[Finding] = []
    ctrl = p.get("EKF2_EV_CTRL")
    if ctrl is None:
        out.append(Finding("error", "EKF2_EV_CTRL", None, "not on this autopilot: PX4 < 1.14?"))
    else:
        bits = int(ctrl)
        if not bits & 1:
            out.append(Finding("error", "EKF2_EV_CTRL", ctrl,
                               "set 15 (horizontal and vertical position, velocity, yaw) or 11"))
        if bits & 4 and output == "vision_position":
            out.append(Finding("warning", "EKF2_EV_CTRL", ctrl,
                               "velocity fusion (bit 2) needs mavlink.output = \"odometry\": PX4 "
                               "ignores VISION_SPEED_ESTIMATE"))
        if p.get("EKF2_HGT_REF") == 3 and not bits & 2:
            out.append(Finding("error", "EKF2_EV_CTRL", ctrl,
                               "set bit 1 (vertical position): EKF2_HGT_REF is Vision"))
    if p.get("EKF2_EV_NOISE_MD") not in (0, None):
        out.append(Finding("warning", "EKF2_EV_NOISE_MD", p["EKF2_EV_NOISE_MD"],
                           "set 0: use the covariance the companion sends"))
    if (p.get("EKF2_EV_QMIN") or 0) > 0 and output == "vision_position":
        out.append(Finding("error", "EKF2_EV_QMIN", p["EKF2_EV_QMIN"],
                           "set 0: VISION_POSITION_ESTIMATE carries no quality"))
    _delay(out, "EKF2_EV_DELAY", p, latency_ms, 300)
    return out


def _delay(out: list[Finding], name: str, p: dict, latency_ms: float | None,
           limit: int) -> None:
    """Compare the delay parameter with the measured capture-to-send latency."""
    if latency_ms is None or p.get(name) is None:
        return
    wanted = min(limit, round(latency_ms))
    if abs(p[name] - wanted) > DELAY_TOLERANCE_MS:
        out.append(Finding("warning", name, p[name],
                           f"set {wanted}: the measured capture-to-send latency"))
