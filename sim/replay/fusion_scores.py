"""What the fusion filter's acceptance asks of a replay, from the received messages and the
flown ground truth (after the start alignment only): position error as a share of the distance
flown while published, heading error, consistency of the covariance the autopilot was sent
(NEES per degree of freedom, and how often an error was beyond 3 sigma), when publication
started and when the map's scale and heading converged (daemon/fusion/alignment.py), counted
from the take-off. The fusion publishes from power-on, with a covariance that says how little
it knows before the map converges.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sim.metrics import Aligned
from sim.sequence import Sequence
from sim.trajectory import Trajectory

TAKEOFF_CLIMB_M = 0.1  # the take-off starts when the height first changed by this much
CHI2_3DOF_3SIGMA = 14.16  # chi-square, 3 dof, with a 3-sigma Gaussian's tail (0.27 %)
VELOCITY_DT = 0.05  # ground-truth velocity: central difference over +-50 ms

FUSION_KEYS = {
    "distance_m": "distance flown between the first and last scored pose, metres",
    "ate_pct_distance": "ate_rmse_m as a percentage of distance_m",
    "heading_rms_deg": "heading (yaw) error RMS of the received attitude, degrees",
    "heading_max_deg": "largest absolute heading error, degrees",
    "heading_frame_rms_deg": "heading error RMS in the autopilot's heading frame (the heading "
                             "error less compass_bias_deg): what the fusion adds to the "
                             "autopilot's own compass error, degrees",
    "heading_frame_max_deg": "largest absolute heading error in the autopilot's heading frame, "
                             "degrees",
    "compass_bias_deg": "heading error of the attitude the autopilot reported, its mean over "
                        "the flight (its compass bias), degrees (None: no synthetic sensors)",
    "nees_position": "position NEES per degree of freedom, mean over the scored poses, "
                     "with the covariance the message carried, in the autopilot's heading "
                     "frame (the truth turned by compass_bias_deg; 1 = consistent)",
    "nees_velocity": "velocity NEES per degree of freedom, as nees_position",
    "tracking_start_s": "sequence time of the first tracked frame, s",
    "first_publish_s": "sequence time of the first received pose, s",
    "takeoff_s": f"sequence time the flight's height first changed by {TAKEOFF_CLIMB_M} m "
                 "(None: it never did)",
    "climb_m": "height gained from the take-off to the highest point, metres",
    "publish_after_takeoff_s": "first_publish_s - takeoff_s (negative: published on the "
                               "ground before the take-off)",
    "aligned_after_takeoff_s": "time from the take-off until the map's scale and heading had "
                               "converged (the fusion's 'aligned'; None: never), s",
    "overconfident_fraction": "share of the received positions whose error is beyond 3 sigma "
                              f"of the covariance they carried (chi-square > {CHI2_3DOF_3SIGMA}, "
                              "3 dof, autopilot's heading frame)",
}


def normalized_errors(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """e^T C^-1 e of the rows whose covariance is finite and invertible."""
    values = []
    for e, C in zip(errors, covariances, strict=True):
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(C))):
            continue
        try:
            values.append(float(e @ np.linalg.solve(C, e)))
        except np.linalg.LinAlgError:
            continue
    return np.array(values)


def nees_per_dof(errors: np.ndarray, covariances: np.ndarray) -> float | None:
    """Mean of e^T C^-1 e / dof over the rows whose covariance is finite and invertible."""
    values = normalized_errors(errors, covariances)
    return float(np.mean(values)) / errors.shape[1] if len(values) else None


def yaw_differences(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Yaw of R_a R_b^T for each pair of (N, 3, 3) rotations, radians in (-pi, pi]."""
    delta = np.einsum("nij,nkj->nik", R_a, R_b)
    return np.arctan2(delta[:, 1, 0], delta[:, 0, 0])


def compass_bias_deg(sequence: Sequence) -> float | None:
    """Mean heading error of the attitude the simulated autopilot reports (its compass bias),
    degrees; None for a sequence without synthetic sensors."""
    extras = getattr(sequence, "extras", None) or {}
    sensors, path = extras.get("sensors"), extras.get("path")
    if sensors is None or path is None:
        return None
    yaw = yaw_differences(Rotation.from_quat(sensors.attitude).as_matrix(),
                          path.rotation(sensors.t))
    return float(np.degrees(np.arctan2(np.mean(np.sin(yaw)), np.mean(np.cos(yaw)))))


def turned_about_down(vectors: np.ndarray, angle_deg: float | None) -> np.ndarray:
    """(N, 3) vectors turned about the down axis by `angle_deg` (None: unchanged): NED truth
    as seen in a frame whose north is off by that angle."""
    if not angle_deg:
        return vectors
    return Rotation.from_euler("z", angle_deg, degrees=True).apply(vectors)


def velocity_at(trajectory: Trajectory, times: np.ndarray) -> np.ndarray:
    """Ground-truth velocity by central differences of the interpolated positions."""
    def at(ts: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(ts, trajectory.t, trajectory.positions[:, i])
                                for i in range(3)])
    return (at(times + VELOCITY_DT) - at(times - VELOCITY_DT)) / (2 * VELOCITY_DT)


def heading_errors_deg(aligned: Aligned) -> np.ndarray:
    """Yaw of R_est R_gt^T for each matched pose, degrees in (-180, 180]."""
    return np.degrees(yaw_differences(aligned.estimate.rotations.as_matrix(),
                                      aligned.groundtruth.rotations.as_matrix()))


def takeoff_time(flight: Trajectory, from_t: float) -> tuple[float | None, float]:
    """(time the height first moved TAKEOFF_CLIMB_M from its value at `from_t`, the climb
    from there to the highest point)."""
    keep = flight.t >= from_t
    t, height = flight.t[keep], -flight.positions[keep, 2]
    if len(t) == 0:
        return None, 0.0
    moved = np.flatnonzero(np.abs(height - height[0]) >= TAKEOFF_CLIMB_M)
    if len(moved) == 0:
        return None, 0.0
    return float(t[moved[0]]), float(height.max() - height[0])


def fusion_scores(aligned: Aligned, flight: Trajectory, velocity_error: np.ndarray,
                  position_cov: np.ndarray, velocity_cov: np.ndarray,
                  tracking_start_s: float | None, compass_bias: float | None = None,
                  aligned_t: float | None = None) -> dict:
    """The FUSION_KEYS for matched poses: `velocity_error` and the covariances (N, 3, 3) in
    the local frame are rows of the aligned estimate; `compass_bias` in degrees (None: the
    autopilot's heading frame is taken as true north); `aligned_t` the sequence time the
    map's scale and heading converged."""
    t = aligned.estimate.t
    truth = aligned.groundtruth.positions
    error = aligned.estimate.positions - truth
    start = truth[0]
    frame_error = aligned.estimate.positions - start - turned_about_down(truth - start,
                                                                          compass_bias)
    true_velocity = velocity_at(flight, t)
    frame_velocity_error = (velocity_error + true_velocity
                            - turned_about_down(true_velocity, compass_bias))
    inside = (flight.t >= t[0]) & (flight.t <= t[-1])
    path = flight.positions[inside]
    distance = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    ate = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    heading = heading_errors_deg(aligned)
    frame_heading = (heading - (compass_bias or 0.0) + 180.0) % 360.0 - 180.0
    takeoff, climb = takeoff_time(flight, float(flight.t[0]))
    return {
        "distance_m": distance,
        "ate_pct_distance": 100.0 * ate / distance if distance > 0 else None,
        "heading_rms_deg": float(np.sqrt(np.mean(heading**2))),
        "heading_max_deg": float(np.max(np.abs(heading))),
        "heading_frame_rms_deg": float(np.sqrt(np.mean(frame_heading**2))),
        "heading_frame_max_deg": float(np.max(np.abs(frame_heading))),
        "compass_bias_deg": compass_bias,
        "nees_position": nees_per_dof(frame_error, position_cov),
        "nees_velocity": nees_per_dof(frame_velocity_error, velocity_cov),
        "tracking_start_s": tracking_start_s,
        "first_publish_s": float(t[0]),
        "takeoff_s": takeoff,
        "climb_m": climb,
        "publish_after_takeoff_s": None if takeoff is None else float(t[0]) - takeoff,
        "aligned_after_takeoff_s": (None if takeoff is None or aligned_t is None
                                    else aligned_t - takeoff),
        "overconfident_fraction": _beyond_3_sigma(frame_error, position_cov),
    }


def _beyond_3_sigma(errors: np.ndarray, covariances: np.ndarray) -> float | None:
    values = normalized_errors(errors, covariances)
    return float(np.mean(values > CHI2_3DOF_3SIGMA)) if len(values) else None
