"""ArduPilot's MAVLink handling of vision messages before AP_VisualOdom sees them
(libraries/GCS_MAVLink/GCS_Common.cpp: handle_vision_position_estimate, handle_odometry,
handle_common_vision_position_estimate_data, handle_vision_speed_estimate) and the timestamp
jitter correction every one goes through (libraries/AP_RTC/JitterCorrection.cpp via
correct_offboard_timestamp_usec_to_ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

MAV_FRAME_LOCAL_FRD = 20
MAV_FRAME_BODY_FRD = 12
JITTER_MAX_LAG_S = 0.5  # GCS.h: JitterCorrection lag_correction{500, 100}
JITTER_LOOPS = 100


@dataclass(frozen=True)
class PoseSample:
    """A vision pose as AP_VisualOdom receives it: time on the autopilot's clock after the
    jitter correction, NED position, attitude, the covariance turned into errors (m, rad)."""

    time_s: float
    position: np.ndarray
    attitude: Rotation
    pos_err: float
    ang_err: float
    reset_counter: int
    quality: int


@dataclass(frozen=True)
class VelocitySample:
    """A vision velocity (NED, m/s) as AP_VisualOdom receives it."""

    time_s: float
    velocity: np.ndarray
    reset_counter: int
    quality: int


class JitterCorrection:
    """Maps a sender's timestamps to local time: the smallest (local - remote) offset seen, so
    the least-delayed message counts as arriving with no lag; re-based on the minimum of each
    100 samples to follow clock drift; never more than 500 ms in the past."""

    def __init__(self) -> None:
        self.offset: float | None = None
        self._window_min = math.inf
        self._count = 0

    def correct(self, remote_s: float, local_s: float) -> float:
        diff = local_s - remote_s
        if self.offset is None or diff < self.offset:
            self.offset = diff
        estimate = remote_s + self.offset
        if estimate + JITTER_MAX_LAG_S < local_s:
            estimate = local_s - JITTER_MAX_LAG_S
            self.offset = estimate - remote_s
        self._window_min = min(self._window_min, diff)
        self._count += 1
        if self._count == JITTER_LOOPS:
            self.offset, self._window_min, self._count = self._window_min, math.inf, 0
        return estimate


def covariance_errors(cov: list[float]) -> tuple[float, float]:
    """posErr, angErr from a pose covariance's upper triangle: cbrt of the sum of the squared
    x, y, z (indices 0, 6, 11) and roll, pitch, yaw (15, 18, 20) variances; 0, 0 when the first
    element is NaN (unknown)."""
    if len(cov) < 21 or math.isnan(cov[0]):
        return 0.0, 0.0
    pos = np.cbrt(cov[0] ** 2 + cov[6] ** 2 + cov[11] ** 2)
    ang = np.cbrt(cov[15] ** 2 + cov[18] ** 2 + cov[20] ** 2)
    return float(pos), float(ang)


def vision_samples(msg: object, arrival_s: float, jitter: JitterCorrection
                   ) -> tuple[PoseSample | None, VelocitySample | None]:
    """The pose and velocity a vision message gives AP_VisualOdom; ODOMETRY outside
    LOCAL_FRD/BODY_FRD is dropped silently; VISION_POSITION_ESTIMATE and VISION_SPEED_ESTIMATE
    carry quality 0; ODOMETRY's body-frame velocity is turned to NED by its own attitude."""
    kind = msg.get_type()
    reset = int(getattr(msg, "reset_counter", 0))
    if kind == "VISION_SPEED_ESTIMATE":
        t = jitter.correct(msg.usec / 1e6, arrival_s)
        return None, VelocitySample(t, np.array([msg.x, msg.y, msg.z], float), reset, 0)
    if kind == "VISION_POSITION_ESTIMATE":
        if not np.isfinite([msg.roll, msg.pitch, msg.yaw]).all():
            return None, None
        t = jitter.correct(msg.usec / 1e6, arrival_s)
        attitude = Rotation.from_euler("ZYX", [msg.yaw, msg.pitch, msg.roll])
        pos_err, ang_err = covariance_errors(list(msg.covariance))
        return PoseSample(t, np.array([msg.x, msg.y, msg.z], float), attitude, pos_err,
                          ang_err, reset, 0), None
    if kind != "ODOMETRY" or (msg.frame_id, msg.child_frame_id) != (MAV_FRAME_LOCAL_FRD,
                                                                  MAV_FRAME_BODY_FRD):
        return None, None
    w, x, y, z = msg.q
    if not np.isfinite(msg.q).all() or np.linalg.norm(msg.q) < 1e-6:
        return None, None  # no attitude to turn the velocity or align the yaw with
    t = jitter.correct(msg.time_usec / 1e6, arrival_s)
    attitude = Rotation.from_quat([x, y, z, w])
    pos_err, ang_err = covariance_errors(list(msg.pose_covariance))
    quality = int(msg.quality)
    pose = PoseSample(t, np.array([msg.x, msg.y, msg.z], float), attitude, pos_err, ang_err,
                      reset, quality)
    velocity = attitude.apply([msg.vx, msg.vy, msg.vz])
    return pose, VelocitySample(t, velocity, reset, quality)
