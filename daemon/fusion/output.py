"""The filter's state at a frame as a VisionEstimate: covariance, inflation, quality, and the
continuity check that decides when the autopilot must be told of a discontinuity."""

from __future__ import annotations

import numpy as np

from daemon.estimate import VisionEstimate
from daemon.fusion.config import FusionConfig
from daemon.fusion.state import VEL, NavFilter
from vo.result import Quality

QUALITY_INFLATION_KEYS = {Quality.INSUFFICIENT: "inflate_insufficient", Quality.BAD: "inflate_bad"}
# ODOMETRY's fields are float32: beyond this (or not finite) a value is no estimate
FLOAT32_MAX = float(np.finfo(np.float32).max)
JUMP_FLOOR_M = 0.02  # moves below this are never a discontinuity (a filter at rest is sure to mm)


def inflation(cfg: FusionConfig, quality: str) -> float:
    """Variance factor for a tracking quality ('good' and unknown states: 1)."""
    key = QUALITY_INFLATION_KEYS.get(quality)
    return getattr(cfg, key) if key else 1.0


def attitude_noise(cfg: FusionConfig, quality: str, gap_var: float = 0.0) -> np.ndarray:
    """Covariance of the autopilot's attitude (compass heading noisier than the tilt), plus
    `gap_var` (rad^2: what the vehicle may have turned since or between its samples,
    attitude.py), plus a floor for the tracker's rotation (rad^2, N frame)."""
    tilt, heading, vo = np.radians([cfg.attitude_std_deg, cfg.heading_std_deg,
                                    cfg.vo_rotation_std_deg])
    return (np.diag([tilt**2, tilt**2, heading**2])
            + np.eye(3) * (vo**2 * inflation(cfg, quality) + gap_var))


def quality_percent(position_cov: np.ndarray, good_std_m: float) -> int:
    """ODOMETRY quality from the position uncertainty: 100 at or below `good_std_m`, falling
    as 1/std, never below 1."""
    std = float(np.sqrt(max(np.trace(position_cov) / 3.0, 0.0)))
    if not np.isfinite(std):
        return 1
    return int(np.clip(round(100.0 * good_std_m / max(std, good_std_m)), 1, 100))


def horizontal_std(f: NavFilter) -> float:
    """The position's standard deviation along its least certain horizontal direction."""
    return float(np.sqrt(max(np.linalg.eigvalsh(f.P[:2, :2])[-1], 0.0)))


def build_estimate(f: NavFilter, cfg: FusionConfig, *, R_l_b: np.ndarray, rot_cov: np.ndarray,
                   rates: np.ndarray, t_capture: float, t_source: float, state: str,
                   reset_counter: int) -> VisionEstimate | None:
    """The estimate to send, or None if anything in it is not finite or beyond float32.
    `R_l_b` is the body's attitude in the local frame and `rot_cov` its covariance there.
    The covariance is the filter's, with nothing added: the autopilots apply their own
    floors (VISO_POS_M_NSE, EKF2_EVP_NOISE). It describes errors in the local frame, whose
    north is the autopilot's compass north, the frame the autopilot fuses our poses in, so
    the compass bias is not in it. While the tracker's updates are being rejected, the
    position's covariance also covers the last disagreement between the map and the filter:
    either may be the one gone wrong."""
    factor = inflation(cfg, state)
    position, J = f.at_camera_time()
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3] = factor * (J @ f.P @ J.T)
    if f.vo_disagreement:
        apart = f.vo_disagreement[-1][1]
        pose_cov[:3, :3] += np.outer(apart, apart)
    pose_cov[3:, 3:] = factor * rot_cov
    vel_cov = np.zeros((6, 6))
    vel_cov[:3, :3] = factor * (R_l_b.T @ f.P[VEL, VEL] @ R_l_b)
    vel_cov[3:, 3:] = np.eye(3) * cfg.rate_std_rad_s**2
    velocity = f.x[VEL].copy()
    estimate = VisionEstimate(
        t_capture=t_capture, t_source=t_source, position=position, R_local_body=R_l_b,
        velocity_local=velocity, velocity_body=R_l_b.T @ velocity, angular_rate=rates,
        pose_covariance=pose_cov, velocity_covariance=vel_cov,
        quality=quality_percent(pose_cov[:3, :3], cfg.quality_good_std_m),
        reset_counter=reset_counter, state=state)
    arrays = (estimate.position, R_l_b, velocity, rates, pose_cov, vel_cov)
    return estimate if all(np.all(np.abs(a) <= FLOAT32_MAX) for a in arrays) else None


class Continuity:
    """Remembers the last estimate sent and tells whether the next one jumps: moves from where
    the last one's velocity led further than both covariances allow (chi-square gate, 3 dof).
    A filter update never does that; a restart of the map's scale can. The autopilot must then
    get a new reset_counter rather than fuse the jump."""

    def __init__(self, gate: float):
        self.gate = gate
        self.last: VisionEstimate | None = None

    def jumped(self, e: VisionEstimate) -> bool:
        """Whether `e` is discontinuous with the last estimate; `e` becomes the last."""
        last, self.last = self.last, e
        if last is None:
            return False
        dt = max(e.t_capture - last.t_capture, 0.0)
        d = e.position - (last.position + last.velocity_local * dt)
        if float(np.linalg.norm(d)) <= JUMP_FLOOR_M:
            return False
        motion = np.trace(last.velocity_covariance[:3, :3]) / 3.0 * dt**2
        S = (last.pose_covariance[:3, :3] + e.pose_covariance[:3, :3]
             + np.eye(3) * (motion + JUMP_FLOOR_M**2))
        try:
            return float(d @ np.linalg.solve(S, d)) > self.gate
        except np.linalg.LinAlgError:  # covariances too far apart in size to compare
            return True
