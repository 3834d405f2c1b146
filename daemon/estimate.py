"""The seam between tracking and the autopilot link: an Estimator turns tracker results into
vehicle estimates in the autopilot's local frame.

`PassThroughEstimator` is the estimator used until fusion (the EKF) lands: it applies the
camera mounting and the configured scale, levels the local frame with the autopilot's attitude
when it has one, and differentiates positions for velocity. The EKF implements the same
protocol and takes its place.

Local frame L: earth-fixed FRD (MAV_FRAME_LOCAL_FRD): origin and heading of the body at the
start, z along gravity when the autopilot's roll and pitch are known at that moment.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from daemon.config import MavlinkConfig, MountingConfig
from daemon.mounting import body_from_camera, rotation_vector, rotation_zyx
from vo.result import Quality
from vo.rotation_prior import Orientation

QUALITY_PERCENT = {Quality.GOOD: 100, Quality.INSUFFICIENT: 50, Quality.BAD: 10}
INFLATION = {Quality.GOOD: 1.0, Quality.INSUFFICIENT: 4.0, Quality.BAD: 25.0}  # of the covariance


@dataclass(frozen=True)
class VisionEstimate:
    """One vehicle estimate, ready to encode: everything in SI units, L frame or body FRD."""

    t_capture: float  # CLOCK_MONOTONIC seconds at frame capture
    t_source: float  # the frame's own timestamp (sensor or dataset time)
    position: np.ndarray  # body origin in L, metres
    R_local_body: np.ndarray  # 3x3 attitude of the body in L
    velocity_local: np.ndarray  # m/s in L
    velocity_body: np.ndarray  # m/s in body FRD
    angular_rate: np.ndarray  # rad/s in body FRD
    pose_covariance: np.ndarray  # 6x6, order x y z roll pitch yaw (L frame)
    velocity_covariance: np.ndarray  # 6x6, order vx vy vz (body) rollspeed pitchspeed yawspeed
    quality: int  # ODOMETRY quality percent: 1 worst .. 100 best
    reset_counter: int  # 0..255, changes on every discontinuity
    state: Quality  # the tracker's quality of the frame


class Estimator(Protocol):
    """What the service needs from pass-through and fusion alike."""

    reset_counter: int

    def on_frame(self, result: object, t_capture: float) -> VisionEstimate | None:
        """Consume one tracker FrameResult (tracking thread); an estimate to send, or None."""

    def on_autopilot_message(self, msg: object) -> None:
        """Consume one decoded MAVLink message from the autopilot (asyncio thread)."""

    def bridge(self, t: float) -> VisionEstimate | None:
        """An estimate for time t when no frame has given one for a while (asyncio thread);
        None when nothing but a frame could give one."""

    def orientation(self, t_capture: float) -> Orientation | None:
        """The camera's orientation at a frame's capture time from the autopilot's attitude,
        for the tracker's rotation prior (tracking thread); None when not known."""


def _finite(*arrays: np.ndarray) -> bool:
    return all(np.all(np.isfinite(a)) for a in arrays)


class PassThroughEstimator:
    """Mounting + scale + finite-difference velocity; thread-safe between tracking and link."""

    def __init__(self, mounting: MountingConfig, link: MavlinkConfig):
        self.R_c_b = body_from_camera(mounting).T
        self.scale = mounting.scale
        self.floor = np.array([link.position_std_m] * 3 + [link.angle_std_rad] * 3) ** 2
        self.reset_counter = 0
        self._level = np.eye(3)  # R_L_b from the autopilot's roll and pitch, yaw zero
        self._lock = threading.Lock()
        self._anchor: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # R_L_w, p_w0, p_L0
        self._last: VisionEstimate | None = None
        self._previous: tuple[np.ndarray, np.ndarray, float | None] = (np.zeros(3), np.eye(3), None)

    def bridge(self, t: float) -> VisionEstimate | None:
        """Nothing between frames: without an IMU filter there is nothing to carry a pose."""
        return None

    def orientation(self, t_capture: float) -> Orientation | None:
        """None: the pass-through keeps no attitude history to give the tracker a prior."""
        return None

    def on_autopilot_message(self, msg: object) -> None:
        """Keeps the latest ATTITUDE roll and pitch to level the local frame of a new segment."""
        if msg.get_type() == "ATTITUDE" and _finite(np.array([msg.roll, msg.pitch])):
            with self._lock:
                self._level = rotation_zyx(msg.roll, msg.pitch, 0.0)

    def on_frame(self, result: object, t_capture: float) -> VisionEstimate | None:
        """An estimate for a tracked frame; None while initialising, lost or on a bad pose."""
        if result.new_segment and self._anchor is not None:
            self.reset_counter = (self.reset_counter + 1) % 256
            self._anchor = None
        if not result.has_pose or result.quality not in QUALITY_PERCENT:
            return None
        T_w_c = np.asarray(result.T_w_c, dtype=np.float64)
        if not _finite(T_w_c):
            return None
        R_w_b = T_w_c[:3, :3] @ self.R_c_b
        p_w = T_w_c[:3, 3]
        if self._anchor is None:
            self._start_segment(R_w_b, p_w, result.t)
            return None
        R_L_w, p_w0, p_L0 = self._anchor
        position = p_L0 + self.scale * (R_L_w @ (p_w - p_w0))
        R_L_b = R_L_w @ R_w_b
        estimate = self._with_motion(result, t_capture, position, R_L_b, R_L_w)
        if estimate is not None:
            self._last = estimate
        return estimate

    def _start_segment(self, R_w_b: np.ndarray, p_w: np.ndarray, t: float) -> None:
        """Anchor L: the first segment at the levelled start pose, later ones at the last pose
        sent, so a new map continues where the old one stopped (reset_counter still changes)."""
        if self._last is None:
            with self._lock:
                R_L_b0, p_L0 = self._level.copy(), np.zeros(3)
        else:
            R_L_b0, p_L0 = self._last.R_local_body, self._last.position
        self._anchor = (R_L_b0 @ R_w_b.T, p_w.copy(), p_L0.copy())
        self._previous = (p_L0, R_L_b0, t)

    def _with_motion(self, result: object, t_capture: float, position: np.ndarray,
                     R_L_b: np.ndarray, R_L_w: np.ndarray) -> VisionEstimate | None:
        prev_position, prev_R, prev_t = self._previous
        self._previous = (position, R_L_b, result.t)
        if prev_t is None or result.t <= prev_t:
            return None
        dt = result.t - prev_t
        velocity = (position - prev_position) / dt
        rates = rotation_vector(prev_R.T @ R_L_b) / dt
        tracker_cov = self._tracker_covariance(result.covariance, R_L_w)
        pose_cov = (tracker_cov + np.diag(self.floor)) * INFLATION[result.quality]
        # frame-to-frame differences: two independent pose errors over dt, floored at the
        # configured standard deviations per second
        vel_cov = (2.0 * tracker_cov / dt**2 + np.diag(self.floor)) * INFLATION[result.quality]
        for block in (slice(0, 3), slice(3, 6)):  # both into body FRD
            vel_cov[block, block] = R_L_b.T @ vel_cov[block, block] @ R_L_b
        estimate = VisionEstimate(
            t_capture=t_capture, t_source=float(result.t), position=position, R_local_body=R_L_b,
            velocity_local=velocity, velocity_body=R_L_b.T @ velocity, angular_rate=rates,
            pose_covariance=pose_cov, velocity_covariance=vel_cov,
            quality=QUALITY_PERCENT[result.quality], reset_counter=self.reset_counter,
            state=result.quality)
        if not _finite(estimate.position, estimate.velocity_local, estimate.angular_rate,
                       pose_cov, vel_cov):
            return None
        return estimate

    def _tracker_covariance(self, covariance: object, R_L_w: np.ndarray) -> np.ndarray:
        """The tracker's world-frame pose covariance in L and metres (zeros when it has none)."""
        if covariance is None:
            return np.zeros((6, 6))
        cov = np.asarray(covariance, dtype=np.float64)
        if cov.shape != (6, 6) or not _finite(cov):
            return np.zeros((6, 6))
        rot = np.zeros((6, 6))
        rot[:3, :3] = self.scale * R_L_w
        rot[3:, 3:] = R_L_w
        return rot @ cov @ rot.T
