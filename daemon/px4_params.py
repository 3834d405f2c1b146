"""PX4's parameters for a flight on our vision: EKF2 external-vision control, height reference,
noise floors, quality gate, sensor offset and delay (PX4 src/modules/ekf2/params_external_vision
.yaml; EKF2.cpp: EKF2_EV_NOISE_MD 0 takes the message's variance with EKF2_EVP_NOISE /
EKF2_EVA_NOISE as lower bounds). EV yaw (EKF2_EV_CTRL bit 3) is refused: while it is fused
EKF2 stops the magnetometer's heading (aid_sources/magnetometer/mag_heading_control.cpp starts
and continues only without ev_yaw), and the service's north is the heading PX4 sends it, so
PX4 would be fed its own heading back with no compass behind it. The MAVLink instance's mode
is judged from the streams that arrive (stream_groups.py).
"""

from __future__ import annotations

from daemon.autopilot_params import CheckContext, Finding, Severity, delay_finding

EV_HPOS, EV_VPOS, EV_VEL, EV_YAW = 1, 2, 4, 8  # EKF2_EV_CTRL bits
HGT_REF_VISION = 3
ERROR, WARNING = Severity.ERROR, Severity.WARNING


def px4_findings(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    """Everything wrong in a PX4's external-vision parameters."""
    out = _ev_ctrl(p, ctx)
    if p.get("EKF2_EV_NOISE_MD", 0) != 0:
        out.append(Finding(WARNING, "EKF2_EV_NOISE_MD", p["EKF2_EV_NOISE_MD"],
                           "1 replaces the covariance the service sends by fixed noise", 0))
    floor = p.get("EKF2_EVP_NOISE")
    if floor is not None and floor > ctx.good_std_m + 1e-6:
        out.append(Finding(WARNING, "EKF2_EVP_NOISE", floor, "a floor under our position "
                           f"variance: the service's std is {ctx.good_std_m:g} m when tracking "
                           "well, so at this value its covariance is not used", ctx.good_std_m))
    if (p.get("EKF2_EV_QMIN") or 0) > 0 and ctx.output == "vision_position":
        out.append(Finding(ERROR, "EKF2_EV_QMIN", p["EKF2_EV_QMIN"],
                           "VISION_POSITION_ESTIMATE carries no quality: nothing passes", 0))
    if ctx.fusion:
        for axis in "XYZ":
            name = f"EKF2_EV_POS_{axis}"
            if p.get(name, 0) != 0:
                out.append(Finding(WARNING, name, p[name], "the service sends the position of "
                                   "the autopilot's IMU: EKF2 would correct for the camera "
                                   "offset a second time", 0))
    delay = delay_finding("EKF2_EV_DELAY", p, ctx, 300)
    return out + ([delay] if delay else [])


def _ev_ctrl(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    """EKF2_EV_CTRL: horizontal position needed, never yaw (the service's north is PX4's own
    heading), velocity only from ODOMETRY, vertical position when vision is the height
    reference."""
    if "EKF2_EV_CTRL" not in p:
        return [Finding(ERROR, "EKF2_EV_CTRL", None, "PX4 older than 1.14 (EKF2_AID_MASK): "
                        "update PX4")]
    bits = int(p["EKF2_EV_CTRL"])
    target, why, severity = (bits | EV_HPOS) & ~EV_YAW, [], WARNING
    if not bits & EV_HPOS:
        why.append("bit 0 (horizontal position) makes EKF2 use the vision")
        severity = ERROR
    if bits & EV_YAW:
        why.append("bit 3 (yaw) would feed PX4 its own heading back: the service's north is "
                   "the autopilot's heading")
        severity = ERROR
    if bits & EV_VEL and ctx.output == "vision_position":
        target &= ~EV_VEL
        why.append("bit 2 (velocity) needs mavlink.output = \"odometry\": PX4 ignores "
                   "VISION_SPEED_ESTIMATE")
    if p.get("EKF2_HGT_REF") == HGT_REF_VISION and not bits & EV_VPOS:
        target |= EV_VPOS
        why.append("bit 1 (vertical position): EKF2_HGT_REF is Vision")
        severity = ERROR
    if target == bits:
        return []
    return [Finding(severity, "EKF2_EV_CTRL", bits, "; ".join(why), target)]
