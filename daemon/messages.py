"""MAVLink messages the service sends, built from estimates and health states.

Stamps are CLOCK_MONOTONIC microseconds of frame capture (the clock TIMESYNC answers with).
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon.mounting import euler_zyx, quaternion_wxyz

MAV_CMD_DO_SET_GLOBAL_ORIGIN = 611  # newer than the pymavlink 'common' dialect in use
_UPPER = np.triu_indices(6)

def usec(t: float) -> int:
    """Seconds on the monotonic clock -> integer microseconds."""
    return round(t * 1e6)


def upper_triangle(cov: np.ndarray) -> list[float]:
    """The 21 row-major upper-triangle entries MAVLink uses for a 6x6 covariance."""
    return [float(v) for v in cov[_UPPER]]


def odometry(mav: mavlink2.MAVLink, e: object) -> object:
    """ODOMETRY in LOCAL_FRD / BODY_FRD, the only frame pair both ArduPilot and PX4 accept."""
    return mav.odometry_encode(
        usec(e.t_capture), mavlink2.MAV_FRAME_LOCAL_FRD, mavlink2.MAV_FRAME_BODY_FRD,
        *(float(v) for v in e.position), [float(v) for v in quaternion_wxyz(e.R_local_body)],
        *(float(v) for v in e.velocity_body), *(float(v) for v in e.angular_rate),
        upper_triangle(e.pose_covariance), upper_triangle(e.velocity_covariance),
        reset_counter=e.reset_counter, estimator_type=mavlink2.MAV_ESTIMATOR_TYPE_VIO,
        quality=e.quality)


def vision_position(mav: mavlink2.MAVLink, e: object) -> object:
    """VISION_POSITION_ESTIMATE: position and 3-2-1 Euler attitude in the local frame."""
    return mav.vision_position_estimate_encode(
        usec(e.t_capture), *(float(v) for v in e.position), *euler_zyx(e.R_local_body),
        covariance=upper_triangle(e.pose_covariance), reset_counter=e.reset_counter)


def vision_speed(mav: mavlink2.MAVLink, e: object) -> object:
    """VISION_SPEED_ESTIMATE: velocity in the local (NED-like) frame, 3x3 row-major covariance."""
    R = e.R_local_body
    cov = R @ e.velocity_covariance[:3, :3] @ R.T
    return mav.vision_speed_estimate_encode(
        usec(e.t_capture), *(float(v) for v in e.velocity_local),
        covariance=[float(v) for v in cov.ravel()], reset_counter=e.reset_counter)


def heartbeat(mav: mavlink2.MAVLink, system_status: int) -> object:
    """HEARTBEAT of a companion: ONBOARD_CONTROLLER, autopilot INVALID, and its health as a
    MAV_STATE (daemon/health.py)."""
    return mav.heartbeat_encode(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
                                mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, system_status)
