"""Trajectory accuracy: association by time, Umeyama alignment, ATE and RPE, tracked fraction."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from sdvl.errors import InputError
from sim.trajectory import Trajectory

ALIGNMENTS = ("sim3", "se3", "none")


def interpolate(groundtruth: Trajectory, times: np.ndarray,
                max_gap: float | None = None) -> tuple[Trajectory, np.ndarray]:
    """Ground truth at `times` (linear position, slerp rotation) and the mask of times it covers.

    A time is covered when it falls between two ground-truth samples at most `max_gap` apart
    (default: three times the median sample spacing), or on a sample exactly.
    """
    gt_t = groundtruth.t
    if max_gap is None:
        max_gap = 3.0 * float(np.median(np.diff(gt_t))) if len(gt_t) > 1 else 0.0
    j = np.clip(np.searchsorted(gt_t, times, side="right") - 1, 0, max(len(gt_t) - 2, 0))
    exact = np.isin(times, gt_t)
    inside = (times >= gt_t[0]) & (times <= gt_t[-1])
    if len(gt_t) > 1:
        inside &= (gt_t[j + 1] - gt_t[j]) <= max_gap
    mask = exact | inside
    times = times[mask]
    if len(gt_t) == 1:
        return groundtruth.subset(np.zeros(times.size, dtype=int)), mask
    j = j[mask]
    w = ((times - gt_t[j]) / (gt_t[j + 1] - gt_t[j]))[:, None]
    positions = (1.0 - w) * groundtruth.positions[j] + w * groundtruth.positions[j + 1]
    quats = Slerp(gt_t, groundtruth.rotations)(np.clip(times, gt_t[0], gt_t[-1])).as_quat()
    return Trajectory(times, positions, quats), mask


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool) -> tuple[np.ndarray, np.ndarray,
                                                                         float]:
    """(R, t, s) minimising sum |dst - (s R src + t)|^2 (Umeyama 1991)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    U, D, Vt = np.linalg.svd(xd.T @ xs / len(src))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_s = float((xs**2).sum(axis=1).mean())
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale and var_s > 0 else 1.0
    return R, mu_d - s * R @ mu_s, s


@dataclass
class Evaluation:
    """Accuracy of an estimate against ground truth (metres, degrees)."""

    align: str
    matched: int
    frames: int | None
    tracked: int | None
    tracked_fraction: float | None
    scale: float
    ate_rmse_m: float
    ate_mean_m: float
    ate_median_m: float
    ate_max_m: float
    rot_rmse_deg: float
    rpe_trans_pct: float | None
    rpe_rot_deg_per_m: float | None
    rpe_delta_m: float | None
    path_length_m: float

    def to_dict(self) -> dict:
        """Plain JSON-ready values."""
        return asdict(self)


@dataclass
class Aligned:
    """Ground truth and estimate at matched times, the estimate mapped into the GT frame."""

    groundtruth: Trajectory
    estimate: Trajectory
    R: np.ndarray
    t: np.ndarray
    scale: float


def align_trajectories(groundtruth: Trajectory, estimate: Trajectory,
                       align: str = "sim3") -> Aligned:
    """Associate by time and align the estimate to the ground truth (sim3, se3 or none)."""
    if align not in ALIGNMENTS:
        raise InputError(f"unknown alignment '{align}' (expected one of {', '.join(ALIGNMENTS)})")
    gt, mask = interpolate(groundtruth, estimate.t)
    est = estimate.subset(mask)
    if len(est) < 3:
        raise InputError(f"only {len(est)} estimate poses fall within the ground truth's time "
                         "range; are the timestamps of both files in the same clock?")
    if align == "none":
        R, t, s = np.eye(3), np.zeros(3), 1.0
    else:
        R, t, s = umeyama(est.positions, gt.positions, with_scale=align == "sim3")
    rot = Rotation.from_matrix(R) * est.rotations
    moved = Trajectory(est.t, s * est.positions @ R.T + t, rot.as_quat())
    return Aligned(gt, moved, R, t, s)


def orientation_errors(gt: Rotation, est: Rotation, align: bool) -> np.ndarray:
    """Angles (rad) between ground-truth and estimated orientations, after the one rotation
    that best aligns the orientations themselves when `align` (a position fit says nothing
    about rotation when the camera barely moves)."""
    if align:
        U, _, Vt = np.linalg.svd(np.einsum("nij,nkj->ik", gt.as_matrix(), est.as_matrix()))
        D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
        est = Rotation.from_matrix(U @ D @ Vt) * est
    return (gt.inv() * est).magnitude()


def relative_pose_error(gt: Trajectory, est: Trajectory,
                        delta_m: float) -> tuple[float, float] | None:
    """Mean translation error (% of distance) and rotation error (deg per metre) over segments
    of `delta_m` metres travelled; None when the path is shorter than one segment."""
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt.positions, axis=0),
                                                           axis=1))])
    starts = np.arange(len(gt))
    ends = np.searchsorted(dist, dist + delta_m)
    ok = ends < len(gt)
    if not ok.any():
        return None
    i, j = starts[ok], ends[ok]
    G, E = gt.matrices(), est.matrices()
    rel_gt = np.linalg.inv(G[i]) @ G[j]
    rel_est = np.linalg.inv(E[i]) @ E[j]
    err = np.linalg.inv(rel_gt) @ rel_est
    travelled = dist[j] - dist[i]
    trans = np.linalg.norm(err[:, :3, 3], axis=1) / travelled
    angle = np.degrees(Rotation.from_matrix(err[:, :3, :3]).magnitude()) / travelled
    return float(trans.mean() * 100.0), float(angle.mean())


def count_tracked(frame_times: np.ndarray, estimate_times: np.ndarray) -> int:
    """How many frames have an estimated pose (within half a frame interval of their time)."""
    if len(frame_times) == 0 or len(estimate_times) == 0:
        return 0
    tol = 0.5 * float(np.median(np.diff(frame_times))) if len(frame_times) > 1 else 1e-6
    k = np.searchsorted(estimate_times, frame_times)
    last = len(estimate_times) - 1
    before = np.abs(estimate_times[np.clip(k - 1, 0, last)] - frame_times)
    after = np.abs(estimate_times[np.clip(k, 0, last)] - frame_times)
    nearest = np.minimum(before, after)
    return int((nearest < tol).sum())


def evaluate(groundtruth: Trajectory, estimate: Trajectory, align: str = "sim3",
             frames: int | None = None, rpe_delta_m: float | None = None,
             frame_times: np.ndarray | None = None) -> Evaluation:
    """ATE, rotation error, RPE and tracked fraction of `estimate` against `groundtruth`.

    The tracked fraction counts the `frame_times` that have an estimated pose, or, given only
    the number of `frames`, the poses matched to ground truth; `rpe_delta_m` is the RPE segment
    length (default: a tenth of the path).
    """
    if frame_times is not None:
        frames = len(frame_times)
        tracked = count_tracked(np.asarray(frame_times, dtype=np.float64), estimate.t)
    else:
        tracked = None
    a = align_trajectories(groundtruth, estimate, align)
    errors = np.linalg.norm(a.groundtruth.positions - a.estimate.positions, axis=1)
    rot_err = orientation_errors(a.groundtruth.rotations, a.estimate.rotations, align != "none")
    length = a.groundtruth.path_length()
    delta = rpe_delta_m if rpe_delta_m is not None else length / 10.0
    rpe = relative_pose_error(a.groundtruth, a.estimate, delta) if delta > 0 else None
    if tracked is None and frames:
        tracked = min(len(a.estimate), frames)
    return Evaluation(
        align=align,
        matched=len(a.estimate),
        frames=frames,
        tracked=tracked,
        tracked_fraction=tracked / frames if frames else None,
        scale=a.scale,
        ate_rmse_m=float(np.sqrt(np.mean(errors**2))),
        ate_mean_m=float(errors.mean()),
        ate_median_m=float(np.median(errors)),
        ate_max_m=float(errors.max()),
        rot_rmse_deg=float(np.degrees(np.sqrt(np.mean(rot_err**2)))),
        rpe_trans_pct=None if rpe is None else rpe[0],
        rpe_rot_deg_per_m=None if rpe is None else rpe[1],
        rpe_delta_m=None if rpe is None else delta,
        path_length_m=length,
    )
