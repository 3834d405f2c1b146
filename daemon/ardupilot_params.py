"""ArduPilot's parameters for a flight on our vision: EKF3, the VisualOdom backend, EKF sources,
GPS, arming checks, noise floors and delay (ArduPilot upstream 2025; older names too).

VISO_TYPE 2 is what this recommends, reasoned from AP_VisualOdom_IntelT265.cpp (types 2 and 3
share that backend):
- Type 3 (VOXL), whenever a message's reset_counter differs from the last one it saw, re-aligns
  the yaw to the AHRS and the position, height included, to the last position it recorded. Both
  start at 0 at every boot, so a first message with a counter other than 0 puts the vehicle at
  (0,0,0): the descent into the ground of autopilot-interface.md (e) 3. The service keeps its
  own poses continuous over map resets, so that re-alignment adds nothing but that risk.
- Type 2 (IntelT265) takes the poses as sent, ignores them for 1 s after a reset_counter change
  and refuses to arm while the vision attitude is more than 10 deg from the AHRS's: a wrong
  mounting is caught on the ground. Both types align the vision yaw to the AHRS once; the
  service's north already is the compass's.
- Type 1 (MAVLink) does neither check; it works with this service, but gains nothing.
"""

from __future__ import annotations

from daemon.autopilot_params import (
    ARDUPILOT_POS_NOISE_MIN,
    VISUAL_ODOMETRY_CHECK_BIT,
    CheckContext,
    Finding,
    Severity,
    delay_finding,
    first_name,
)

EXTERNAL_NAV = 6
COMPASS = 1
RECOMMENDED_VISO_TYPE = 2
ERROR, WARNING, NOTE = Severity.ERROR, Severity.WARNING, Severity.NOTE
VISO_TYPE_WHY = {
    0: "ArduPilot ignores vision messages; 2 takes our poses as sent and checks our attitude "
       "before arming",
    1: "works with this service, but 2 adds ArduPilot's pre-arm check that our attitude agrees "
       "with its own within 10 deg, which catches a wrong camera mounting",
    3: "works with this service, but 2 is safer: type 3 re-aligns position and height to the "
       "last position it recorded whenever reset_counter differs from what it last saw, and "
       "that record is (0,0,0) after every autopilot boot (a message with reset_counter > 0 "
       "then puts the vehicle at height 0); our poses are already continuous over map resets",
}


def ardupilot_findings(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    """Everything wrong or worth knowing in an ArduPilot's parameters."""
    return [*_ekf(p), *_visual_odometry(p, ctx), *_sources(p, ctx), *_gps_and_origin(p, ctx),
            *_arming(p), *_noise_and_delay(p, ctx)]


def _want(p: dict[str, float], name: str, ok: bool, set_to: float, why: str,
          severity: Severity = ERROR, missing: str = "") -> list[Finding]:
    if name not in p:
        return [Finding(ERROR, name, None, missing)] if missing else []
    return [] if ok else [Finding(severity, name, p[name], why, set_to)]


def _ekf(p: dict[str, float]) -> list[Finding]:
    return [*_want(p, "AHRS_EKF_TYPE", p.get("AHRS_EKF_TYPE") == 3, 3,
                   "external navigation needs EKF3 (reboot)"),
            *_want(p, "EK3_ENABLE", p.get("EK3_ENABLE") == 1, 1, "EKF3 must run (reboot)")]


def _visual_odometry(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    viso = p.get("VISO_TYPE")
    out = _want(p, "VISO_TYPE", viso == RECOMMENDED_VISO_TYPE, RECOMMENDED_VISO_TYPE,
                VISO_TYPE_WHY.get(viso, "not a type this service works with") + " (reboot)",
                WARNING if viso in (1, 3) else ERROR,
                missing="this firmware has no VisualOdom (boards with 1 MB of flash leave it "
                        "out): load a build with it, e.g. from custom.ardupilot.org")
    out += _want(p, "VISO_ORIENT", p.get("VISO_ORIENT") == 0, 0,
                 "the service sends the vehicle's attitude, not the camera's: ArduPilot would "
                 "turn it and refuse to arm (yaw or roll/pitch diff)")
    out += _want(p, "VISO_SCALE", p.get("VISO_SCALE") == 1, 1,
                 "ArduPilot would scale the service's metric positions: wrong positions with a "
                 "confident covariance")
    if ctx.fusion:
        for axis in "XYZ":
            name = f"VISO_POS_{axis}"
            out += _want(p, name, p.get(name) == 0, 0, "the service sends the position of the "
                         "autopilot's IMU (its lever arm is fusion.camera_*_m): EKF3 would "
                         "correct for the camera offset a second time", WARNING)
    if ctx.output == "vision_position":
        out += _want(p, "VISO_QUAL_MIN", p.get("VISO_QUAL_MIN", 0) <= 0, 0,
                     "VISION_POSITION_ESTIMATE carries no quality (ArduPilot counts it as 0)")
    else:
        out += _want(p, "VISO_QUAL_MIN", p.get("VISO_QUAL_MIN", 0) >= 0, 0,
                     "at -1 samples the service marks failed (quality -1) are fused", WARNING)
    return out


def _sources(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    gps_yaw_ok = ctx.gps_present is not False
    yaw = p.get("EK3_SRC1_YAW")
    out = _want(p, "EK3_SRC1_POSXY", p.get("EK3_SRC1_POSXY") == EXTERNAL_NAV, EXTERNAL_NAV,
                "6 (ExternalNav): EKF3 takes horizontal position from the vision",
                missing="no EKF source parameters: ArduPilot older than 4.1, which this "
                        "service does not support")
    out += _want(p, "EK3_SRC1_VELXY", p.get("EK3_SRC1_VELXY") in (0, EXTERNAL_NAV),
                 EXTERNAL_NAV, "6 (ExternalNav) or 0: velocity from another source fights the "
                 "vision")
    out += _want(p, "EK3_SRC1_POSZ", p.get("EK3_SRC1_POSZ") in (1, 2, EXTERNAL_NAV), 1,
                 "1 (Baro): the height must come from a sensor this vehicle has")
    out += _want(p, "EK3_SRC1_VELZ", p.get("EK3_SRC1_VELZ") in (0, EXTERNAL_NAV), EXTERNAL_NAV,
                 "6 (ExternalNav) or 0: vertical velocity from another source fights the vision")
    out += _want(p, "EK3_SRC1_YAW", yaw == COMPASS or (yaw in (2, 3) and gps_yaw_ok), COMPASS,
                 "1 (Compass): the service takes its north from the autopilot's heading, so "
                 "ExternalNav yaw (6) would feed the autopilot its own heading back with no "
                 "compass behind it" if yaw == EXTERNAL_NAV else
                 "1 (Compass): this yaw source needs a sensor the vehicle does not have")
    if yaw == COMPASS or "EK3_SRC1_YAW" not in p:
        out += _want(p, "COMPASS_USE", p.get("COMPASS_USE", 1) == 1, 1,
                     "EKF3's heading comes from the compass, and the service's north from it")
    return out


def _gps_and_origin(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    name = first_name(p, "GPS1_TYPE", "GPS_TYPE")
    gps_type = p.get(name)
    out = []
    if gps_type not in (None, 0) and ctx.gps_present is False:
        out.append(Finding(ERROR, name, gps_type, "no GPS answers (GPS_RAW_INT fix type 0): "
                           "ArduPilot keeps looking for one and refuses to arm ('GPS 1: was not "
                           "found'); 0 leaves position to the vision (reboot)", 0))
    elif gps_type not in (None, 0) and ctx.gps_present is None:
        out.append(Finding(NOTE, name, gps_type, "could not tell whether a GPS is connected; "
                           "without one set 0, or ArduPilot refuses to arm"))
    elif ctx.gps_present:
        out.append(Finding(NOTE, "GPS", None, "a GPS is connected: EK3_SRC1 takes position from "
                           "the vision, so it does not fight it; the EKF origin comes from the "
                           "GPS", is_param=False))
    no_gps = ctx.gps_present is False or gps_type == 0
    if no_gps and ctx.origin_enabled is False:
        out.append(Finding(ERROR, "origin.enabled", None, "set [origin] enabled = true with the "
                           "site's latitude and longitude in the service config: without GPS "
                           "EKF3 uses positions only once the service has given it an origin",
                           is_param=False))
    elif no_gps and ctx.origin_enabled is None:
        out.append(Finding(NOTE, "origin.enabled", None, "without GPS the service must set the "
                           "EKF origin: [origin] enabled = true in its config", is_param=False))
    return out


def _arming(p: dict[str, float]) -> list[Finding]:
    """The VisualOdometry arming check: ARMING_SKIPCHK (skip bits, 4.7+) or ARMING_CHECK."""
    off = ("the VisualOdometry arming check is off: ArduPilot would arm with no vision "
           "arriving and fly on dead reckoning")
    if "ARMING_SKIPCHK" in p:
        skip = int(p["ARMING_SKIPCHK"])
        if skip & VISUAL_ODOMETRY_CHECK_BIT:
            return [Finding(WARNING, "ARMING_SKIPCHK", skip, off + " (bit 18)",
                            skip & ~VISUAL_ODOMETRY_CHECK_BIT)]
    elif "ARMING_CHECK" in p:
        check = int(p["ARMING_CHECK"])
        if not check & 1 and not check & VISUAL_ODOMETRY_CHECK_BIT:
            return [Finding(WARNING, "ARMING_CHECK", check, off + " (bit 18)",
                            1 if check == 0 else check | VISUAL_ODOMETRY_CHECK_BIT)]
    if p.get("VISO_TYPE", 0) == 0:
        return []
    return [Finding(NOTE, "arming", None, "ArduPilot refuses to arm until vision arrives "
                    "('PreArm: VisOdom: not healthy'), with VISO_TYPE 2 or 3 also until our "
                    "attitude is within 10 deg of its own: the service sends from power-on, so "
                    "start it and wait for 'VIO: tracking good' before arming", is_param=False)]


def ardupilot_position_error(std_m: float) -> tuple[float, float]:
    """The position error ArduPilot derives from a covariance of `std_m` per axis: 4.7+
    (GCS_Common.cpp, ArduPilot PR #32084) sqrt of the summed variances; before, the cube root
    of the summed squared variances."""
    variance = std_m**2
    return (3 * variance) ** 0.5, (3 * variance**2) ** (1 / 3)


def _noise_and_delay(p: dict[str, float], ctx: CheckContext) -> list[Finding]:
    out = []
    floor = p.get("VISO_POS_M_NSE")
    if floor is not None and floor > ARDUPILOT_POS_NOISE_MIN + 1e-6:
        new, old = ardupilot_position_error(ctx.good_std_m)
        out.append(Finding(WARNING, "VISO_POS_M_NSE", floor, "a floor under the error ArduPilot "
                           f"takes from our covariance: at our best ({ctx.good_std_m:g} m per "
                           f"axis) it derives {new:.3f} m (4.7+) or {old:.3f} m (before), so our "
                           "covariance is ignored until it is several times worse; "
                           f"{ARDUPILOT_POS_NOISE_MIN:g} is the lowest ArduPilot documents",
                           ARDUPILOT_POS_NOISE_MIN))
    delay = delay_finding("VISO_DELAY_MS", p, ctx, 250)
    return out + ([delay] if delay else [])
