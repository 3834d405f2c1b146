"""The filter's state at a frame as a VisionEstimate: covariance, inflation, quality."""

from __future__ import annotations

import numpy as np

from daemon.estimate import VisionEstimate
from daemon.fusion.config import FusionConfig
from daemon.fusion.state import POS, THETA, VEL, NavFilter

QUALITY_INFLATION_KEYS = {"insufficient": "inflate_insufficient", "bad": "inflate_bad"}


def inflation(cfg: FusionConfig, quality: str) -> float:
    """Variance factor for a tracking quality ('good' and unknown states: 1)."""
    key = QUALITY_INFLATION_KEYS.get(quality)
    return getattr(cfg, key) if key else 1.0


def quality_percent(position_cov: np.ndarray, good_std_m: float) -> int:
    """ODOMETRY quality from the position uncertainty: 100 at or below `good_std_m`, falling
    as 1/std, never below 1."""
    std = float(np.sqrt(max(np.trace(position_cov) / 3.0, 0.0)))
    if not np.isfinite(std):
        return 1
    return int(np.clip(round(100.0 * good_std_m / max(std, good_std_m)), 1, 100))


def build_estimate(f: NavFilter, cfg: FusionConfig, *, R_w_b: np.ndarray, rot_cov_w: np.ndarray,
                   rates: np.ndarray, t_capture: float, t_source: float, state: str,
                   reset_counter: int) -> VisionEstimate | None:
    """The estimate to send, or None if anything in it is not finite. Its covariance is the
    filter's, with nothing added: the autopilots apply their own floors (VISO_POS_M_NSE,
    EKF2_EVP_NOISE), and a floor here would make the covariance dishonest. It describes errors
    in the local frame, whose north is the autopilot's compass north: the compass bias turns
    that frame against true north, and the autopilot, fusing our poses in its own heading frame,
    neither sees nor could use that (carried as position noise it grew with the distance from
    the start, 0.5 m std at 30 m, and would have made the autopilot trust the poses less the
    farther it flew)."""
    R_l_b = f.R_nom @ R_w_b
    factor = inflation(cfg, state)
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3] = factor * f.P[POS, POS]
    pose_cov[3:, 3:] = factor * (f.P[THETA, THETA] + f.R_nom @ rot_cov_w @ f.R_nom.T)
    vel_cov = np.zeros((6, 6))
    vel_cov[:3, :3] = factor * (R_l_b.T @ f.P[VEL, VEL] @ R_l_b)
    vel_cov[3:, 3:] = np.eye(3) * cfg.rate_std_rad_s**2
    velocity = f.x[VEL].copy()
    estimate = VisionEstimate(
        t_capture=t_capture, t_source=t_source, position=f.x[POS].copy(), R_local_body=R_l_b,
        velocity_local=velocity, velocity_body=R_l_b.T @ velocity, angular_rate=rates,
        pose_covariance=pose_cov, velocity_covariance=vel_cov,
        quality=quality_percent(pose_cov[:3, :3], cfg.quality_good_std_m),
        reset_counter=reset_counter, state=state)
    arrays = (estimate.position, R_l_b, velocity, rates, pose_cov, vel_cov)
    return estimate if all(np.all(np.isfinite(a)) for a in arrays) else None
