"""Autopilot MAVLink messages turned into sensor samples in SI units on the autopilot's clock.

What ArduPilot and PX4 stream and in which units:
- HIGHRES_IMU (PX4): time_usec, acceleration m/s^2, rates rad/s, abs_pressure hPa
  (fields_updated bit 9 says the pressure is new).
- SCALED_IMU (both): time_boot_ms, acceleration mG, rates mrad/s.
- RAW_IMU (ArduPilot's default stream): time_usec; on ArduPilot the same units as SCALED_IMU.
- ATTITUDE: time_boot_ms, roll/pitch/yaw rad (yaw from the compass), body rates rad/s.
- DISTANCE_SENSOR: time_boot_ms, current/min/max_distance cm, orientation
  (MAV_SENSOR_ROTATION_PITCH_270 = 25 points down).
- SCALED_PRESSURE: time_boot_ms, press_abs hPa.
- ALTITUDE (PX4): time_usec, altitude_monotonic m (barometric, never reset in flight).
- LOCAL_POSITION_NED (both): time_boot_ms, the autopilot's own position estimate, m NED.
- EXTENDED_SYS_STATE (both, no stamp): landed_state from the autopilot's land detector.
- HEARTBEAT (no stamp): base_mode's MAV_MODE_FLAG_SAFETY_ARMED; ArduCopter's system_status.
Accelerations are specific force in body FRD (about -9.81 m/s^2 on z at rest).
Anything not finite or out of its sensor's range is dropped here, so the filter never sees it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_watch import is_autopilot_heartbeat
from daemon.mounting import rotation_zyx

GRAVITY = 9.80665
MG = GRAVITY / 1000.0
DOWNWARD = mavlink2.MAV_SENSOR_ROTATION_PITCH_270
HIGHRES_ACCEL_BITS = 0b111
HIGHRES_PRESSURE_BIT = 1 << 9
# one stream of each kind is fused: the first of these that streams steadily (source_choice.py)
IMU_PRIORITY = {"HIGHRES_IMU": 0, "SCALED_IMU": 1, "RAW_IMU": 2}
BARO_PRIORITY = {"SCALED_PRESSURE": 0, "HIGHRES_IMU": 1, "ALTITUDE": 2}
MAX_ALTITUDE_M = 12000.0
MAX_SPECIFIC_FORCE = 16 * GRAVITY  # beyond any accelerometer's range: a corrupt sample
MIN_PRESSURE_HPA, MAX_PRESSURE_HPA = 100.0, 1200.0


@dataclass(frozen=True)
class Imu:
    """Specific force in body FRD, m/s^2."""

    t: float
    accel: np.ndarray
    source: str


@dataclass(frozen=True)
class Attitude:
    """The autopilot's attitude: R_N_b (body FRD to NED) and body rates."""

    t: float
    R_n_b: np.ndarray
    rates: np.ndarray
    gap_var: float = 0.0  # rad^2 per axis: what the vehicle may have turned where no sample is


@dataclass(frozen=True)
class Range:
    """Distance along the body's down axis to the ground, metres."""

    t: float
    distance: float


@dataclass(frozen=True)
class Baro:
    """Barometric altitude (up positive), metres."""

    t: float
    altitude: float
    source: str


@dataclass(frozen=True)
class LocalPosition:
    """The autopilot's own position estimate (LOCAL_POSITION_NED), metres NED."""

    t: float
    position: np.ndarray


Sample = Imu | Attitude | Range | Baro | LocalPosition
ARDUPILOT_LANDED = {mavlink2.MAV_STATE_STANDBY: True, mavlink2.MAV_STATE_ACTIVE: False}
LANDED = {mavlink2.MAV_LANDED_STATE_ON_GROUND: True, mavlink2.MAV_LANDED_STATE_IN_AIR: False,
          mavlink2.MAV_LANDED_STATE_TAKEOFF: False, mavlink2.MAV_LANDED_STATE_LANDING: False}


def pressure_altitude(hpa: float) -> float:
    """Standard-atmosphere altitude of a static pressure, metres."""
    return 44330.77 * (1.0 - (hpa / 1013.25) ** 0.190263)


def remote_time(msg: object) -> float | None:
    """The message's own timestamp in seconds on the autopilot's clock, if it has one."""
    if hasattr(msg, "time_usec"):
        return msg.time_usec * 1e-6
    if hasattr(msg, "time_boot_ms"):
        return msg.time_boot_ms * 1e-3
    return None


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _imu(t: float, accel: np.ndarray, source: str) -> Imu | None:
    if not np.all(np.isfinite(accel)) or np.linalg.norm(accel) > MAX_SPECIFIC_FORCE:
        return None
    return Imu(t, accel, source)


def _highres(msg: object, t: float) -> list[Sample]:
    out: list[Sample] = []
    if msg.fields_updated & HIGHRES_ACCEL_BITS:
        imu = _imu(t, np.array([msg.xacc, msg.yacc, msg.zacc], float), "HIGHRES_IMU")
        out += [imu] if imu else []
    if msg.fields_updated & HIGHRES_PRESSURE_BIT:
        out += _baro(t, msg.abs_pressure, "HIGHRES_IMU")
    return out


def _scaled_imu(msg: object, t: float) -> list[Sample]:
    imu = _imu(t, np.array([msg.xacc, msg.yacc, msg.zacc], float) * MG, msg.get_type())
    return [imu] if imu else []


def _attitude(msg: object, t: float) -> list[Sample]:
    angles = (msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    if not _finite(*angles) or max(abs(a) for a in angles[:3]) > 2 * math.pi:
        return []
    rates = np.array(angles[3:], float)
    return [Attitude(t, rotation_zyx(msg.roll, msg.pitch, msg.yaw), rates)]


def _distance(msg: object, t: float) -> list[Sample]:
    if msg.orientation != DOWNWARD:
        return []
    if not msg.min_distance <= msg.current_distance <= msg.max_distance:
        return []  # out of range readings are reported as min or max; neither is a measurement
    if msg.current_distance <= 0:
        return []
    return [Range(t, msg.current_distance / 100.0)]


def _baro(t: float, hpa: float, source: str) -> list[Sample]:
    if not _finite(hpa) or not MIN_PRESSURE_HPA <= hpa <= MAX_PRESSURE_HPA:
        return []
    return [Baro(t, pressure_altitude(hpa), source)]


def _pressure(msg: object, t: float) -> list[Sample]:
    return _baro(t, msg.press_abs, "SCALED_PRESSURE")


def _altitude(msg: object, t: float) -> list[Sample]:
    h = msg.altitude_monotonic
    if not _finite(h) or abs(h) > MAX_ALTITUDE_M:
        return []
    return [Baro(t, float(h), "ALTITUDE")]


def _local_position(msg: object, t: float) -> list[Sample]:
    p = np.array([msg.x, msg.y, msg.z], float)
    if not np.all(np.isfinite(p)) or float(np.max(np.abs(p))) > MAX_ALTITUDE_M:
        return []
    return [LocalPosition(t, p)]


PARSERS = {"HIGHRES_IMU": _highres, "SCALED_IMU": _scaled_imu, "RAW_IMU": _scaled_imu,
           "ATTITUDE": _attitude, "DISTANCE_SENSOR": _distance, "SCALED_PRESSURE": _pressure,
           "ALTITUDE": _altitude, "LOCAL_POSITION_NED": _local_position}


def flight_states(msg: object) -> list[tuple[str, bool | None]]:
    """("landed", on the ground or None when the autopilot cannot tell) and ("armed", flag) that
    a message says: EXTENDED_SYS_STATE's landed state; an autopilot HEARTBEAT's armed flag and,
    from ArduPilot, its system status (ArduCopter reports STANDBY exactly while its land
    detector says landed, ACTIVE in flight: GCS_MAVLINK_Copter::vehicle_system_status)."""
    kind = msg.get_type()
    if kind == "EXTENDED_SYS_STATE":
        return [("landed", LANDED.get(msg.landed_state))]
    if (kind != "HEARTBEAT" or not isinstance(msg.base_mode, int)  # a corrupt one: not read
            or not is_autopilot_heartbeat(msg)):
        return []
    states = [("armed", bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED))]
    if msg.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
        states.append(("landed", ARDUPILOT_LANDED.get(msg.system_status)))
    return states


def parse(msg: object) -> tuple[float, list[Sample]] | None:
    """(autopilot time, samples) of a message fusion uses; None for any other message.
    Sample times are left on the autopilot's clock; the caller maps them to ours."""
    parser = PARSERS.get(msg.get_type())
    t = remote_time(msg) if parser else None
    if t is None or not math.isfinite(t):
        return None
    return t, parser(msg, t)
