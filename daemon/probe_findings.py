"""Findings from what check-autopilot heard on the link: the streams the service needs, whether
a serial link's baud rate carries them and our vision messages, the MAVLink version of the port
and the autopilot's own pre-arm failures."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_params import CheckContext, Finding, Severity
from daemon.autopilot_probe import Probe
from daemon.stream_groups import (
    MAVLINK_PROTOCOLS,
    ParamHint,
    Presence,
    generic_hint,
    mavlink_ports,
    stream_hints,
)
from daemon.streams import StreamStatus

SCALE_SOURCES = ("IMU", "barometer", "downward rangefinder")
# pre-arm failures that only mean no vision has reached the EKF yet (the service is stopped
# while check-autopilot holds the port)
NEEDS_VISION = ("visodom", "position estimate", "ekf", "ahrs")
ERROR, WARNING, NOTE = Severity.ERROR, Severity.WARNING, Severity.NOTE
FRAME_OVERHEAD = 12  # MAVLink 2 header and checksum, unsigned
BITS_PER_BYTE = 10  # a UART byte with start and stop bits
BUSY = 0.7  # of a link's capacity: beyond this, queues grow at every burst
VISION_MESSAGES = {"odometry": ("ODOMETRY",),
                   "vision_position": ("VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE"),
                   "both": ("ODOMETRY", "VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE")}


def probe_findings(probe: Probe, ctx: CheckContext) -> list[Finding]:
    """Streams, link capacity, MAVLink version and pre-arm findings."""
    return [*_streams(probe), *_link_capacity(probe, ctx), *_mavlink_version(probe),
            *_prearm(probe)]


def frame_bytes(message: str) -> int:
    """A MAVLink 2 frame of `message` with every field filled."""
    return getattr(mavlink2, f"MAVLink_{message.lower()}_message").unpacker.size + FRAME_OVERHEAD


def _link_capacity(probe: Probe, ctx: CheckContext) -> list[Finding]:
    """A UART carries baud/10 bytes a second each way: our vision messages at the camera's rate
    one way, the streams the service asks for the other."""
    if not probe.baud or probe.usb:
        return []
    out_bps = ctx.vision_rate_hz * sum(map(frame_bytes, VISION_MESSAGES[ctx.output]))
    in_bps = sum(s.need.rate_hz * frame_bytes(s.need.request) for s in probe.streams)
    load = max(out_bps, in_bps) / (probe.baud / BITS_PER_BYTE)
    if load <= BUSY:
        return []
    return [Finding(ERROR if load > 1 else WARNING, "baud rate", None,
                    f"{probe.baud} baud carries {probe.baud // BITS_PER_BYTE} bytes/s; the "
                    f"vision messages need {out_bps:.0f} and the streams {in_bps:.0f} "
                    f"({load:.0%}): set the autopilot port's baud rate (ArduPilot SERIALn_BAUD "
                    "921, PX4 SER_TELn_BAUD 921600) and mavlink.link's to 921600",
                    is_param=False)]


def _rates(probe: Probe, unasked: bool) -> str:
    rates = [(s.need.kind, probe.unasked[s.need.kind] if unasked else s.rate_hz)
             for s in probe.streams]
    return ", ".join(f"{name} {hz:.0f}" for name, hz in rates) + " Hz"


def _streams(probe: Probe) -> list[Finding]:
    out = [Finding(NOTE, "streams", None, f"heard on this port before asking: "
                   f"{_rates(probe, True)}; after asking as the service does: "
                   f"{_rates(probe, False)}", is_param=False)]
    missing = {s.need.kind for s in probe.streams if not s.usable}
    for status in probe.streams:
        if status.usable:
            continue
        if status.need.presence == Presence.ALWAYS:
            out.append(_missing_stream(probe, status))
        elif status.need.presence == Presence.SENSOR and status.rate_hz == 0:
            out.append(Finding(NOTE, status.need.request, None, "no downward rangefinder "
                               "streams: the scale comes from the IMU and the barometer",
                               is_param=False))
        elif status.rate_hz == 0:
            out.append(Finding(NOTE, status.need.request, None, "not sent yet: the autopilot "
                               "sends it once its EKF has a position (after vision arrives)",
                               is_param=False))
    if all(kind in missing for kind in SCALE_SOURCES):
        out.append(Finding(ERROR, "scale", None, "no IMU, barometer or rangefinder arrives: the "
                           "service cannot find the map's scale and never publishes",
                           is_param=False))
    return out


def _consistent(probe: Probe, status: StreamStatus, hints: list[ParamHint]) -> list[ParamHint]:
    """ArduPilot: keep the ports whose configured group rate matches what was heard unasked
    (a port streaming a group at its parameter's rate is that port)."""
    heard = probe.unasked[status.need.kind]
    kept = [h for h in hints if h.name in probe.params
            and (probe.params[h.name] == 0) == (heard < 0.5)
            and (heard < 0.5 or heard >= 0.3 * probe.params[h.name])]
    return kept or hints


def _missing_stream(probe: Probe, status: StreamStatus) -> Finding:
    need = status.need
    hints = stream_hints(probe.flavour, need, probe.params, probe.usb)
    if probe.flavour == "ardupilot":
        hints = _consistent(probe, status, hints)
    severity = ERROR if need.kind == "attitude" else WARNING
    asked = f"SET_MESSAGE_INTERVAL {status.answer.value}"
    if status.answer.value != "accepted":
        asked += f", then {status.method}"
    why = (f"{need.request} ({need.kind}) arrives at {status.rate_hz:.1f} Hz, the service "
           f"needs {need.min_hz:g} Hz ({asked})")
    if severity == ERROR:
        why += ": the service never publishes without it"
    if len(hints) == 1:
        hint = hints[0]
        return Finding(severity, hint.name, probe.params.get(hint.name), why, hint.value)
    fix = " or ".join(map(str, hints)) if hints else generic_hint(probe.flavour, need)
    return Finding(severity, need.request, None, f"{why}: set {fix}", is_param=False)


def _mavlink_version(probe: Probe) -> list[Finding]:
    if not probe.mavlink1:
        return []
    why = ("the autopilot still sends MAVLink 1 after hearing MAVLink 2: ODOMETRY's quality "
           "and reset_counter and the covariances are MAVLink 2 fields it would not read")
    if probe.flavour != "ardupilot":
        return [Finding(ERROR, "MAV_PROTO_VER", probe.params.get("MAV_PROTO_VER"), why, 2)]
    ports = [x for x in mavlink_ports(probe.params) if x != 0 or probe.usb]
    v1 = [x for x in ports if probe.params.get(f"SERIAL{x}_PROTOCOL") == MAVLINK_PROTOCOLS[0]]
    if len(v1) == 1:
        name = f"SERIAL{v1[0]}_PROTOCOL"
        return [Finding(ERROR, name, probe.params[name], why + " (reboot)", 2)]
    return [Finding(ERROR, "SERIALx_PROTOCOL", None, why + ": set 2 on the companion's port",
                    is_param=False)]


def _prearm(probe: Probe) -> list[Finding]:
    if probe.prearm is None:
        return [Finding(NOTE, "pre-arm", None, "the autopilot did not run its pre-arm checks "
                        "on request (MAV_CMD_RUN_PREARM_CHECKS)", is_param=False)]
    out = []
    for text in probe.prearm:
        if any(word in text.lower() for word in NEEDS_VISION):
            out.append(Finding(NOTE, "pre-arm", None, f"'{text}': expected while the service is "
                               "stopped; it clears once the service sends vision",
                               is_param=False))
        else:
            out.append(Finding(ERROR, "pre-arm", None, f"'{text}': the autopilot will refuse "
                               "to arm for this", is_param=False))
    return out
