"""Rigid motion between two sets of matched 3D points: least squares by SVD (Kabsch / Umeyama
without scale, Umeyama 1991), for many hypotheses at once, inside RANSAC over 3-point
samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# a sample whose points span less than this (m, second singular value of the centred set)
# is nearly collinear: its rotation about that line is undetermined
MIN_SPREAD_M = 1e-3


def rigid_fit(src: np.ndarray, dst: np.ndarray,
              weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R (..., 3, 3), t (..., 3) minimising sum w |dst - (R src + t)|^2 over the points of
    each set (src, dst: (..., n, 3); weights (..., n), default 1), and each set's spread
    (second singular value of the centred src, m)."""
    w = np.ones(src.shape[:-1]) if weights is None else weights
    w = (w / w.sum(axis=-1, keepdims=True))[..., None]
    ms, md = (w * src).sum(axis=-2, keepdims=True), (w * dst).sum(axis=-2, keepdims=True)
    xs, xd = src - ms, dst - md
    U, _, Vt = np.linalg.svd(np.swapaxes(w * xd, -1, -2) @ xs)
    S = np.broadcast_to(np.eye(3), U.shape).copy()
    S[..., 2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ S @ Vt
    t = md[..., 0, :] - (R @ ms[..., 0, :, None])[..., 0]
    spread = np.linalg.svd(xs, compute_uv=False)[..., 1] / np.sqrt(src.shape[-2])
    return R, t, spread


@dataclass
class RigidMotion:
    """The outcome of `ransac_rigid`: dst = R src + t, its inlier mask and hypothesis count."""

    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    hypotheses: int


def ransac_rigid(src: np.ndarray, dst: np.ndarray, threshold: np.ndarray, hypotheses: int,
                 rng: np.random.Generator, weights: np.ndarray | None = None,
                 refinements: int = 2) -> RigidMotion | None:
    """The rigid motion dst = R src + t (points (N, 3)) that most point pairs agree with:
    `hypotheses` fits to random 3-point samples, the one with most pairs closer than their
    `threshold` (N,) m wins, then it is refitted to its inliers `refinements` times with the
    pairs' `weights` (N,; the inverse of their noise variance). None with fewer than 3 pairs
    or when no sample is spread out enough."""
    n = len(src)
    if n < 3:
        return None
    samples = rng.integers(0, n, (hypotheses, 3))
    samples = samples[(samples[:, 0] != samples[:, 1]) & (samples[:, 0] != samples[:, 2])
                      & (samples[:, 1] != samples[:, 2])]
    if not len(samples):
        return None
    R, t, spread = rigid_fit(src[samples], dst[samples])
    ok = spread > MIN_SPREAD_M
    if not ok.any():
        return None
    R, t = R[ok], t[ok]
    moved = np.einsum("hij,nj->hni", R, src) + t[:, None, :]
    votes = np.linalg.norm(moved - dst[None], axis=2) < threshold[None]
    best = int(np.argmax(votes.sum(axis=1)))
    R, t, inliers = R[best], t[best], votes[best]
    for _ in range(refinements):
        if inliers.sum() < 3:
            break
        R, t, _ = rigid_fit(src[inliers], dst[inliers],
                            None if weights is None else weights[inliers])
        inliers = np.linalg.norm(src @ R.T + t - dst, axis=1) < threshold
    return RigidMotion(R, t, inliers, int(ok.sum()))


def motion_covariance(R: np.ndarray, t: np.ndarray, src: np.ndarray,
                      dst: np.ndarray) -> np.ndarray:
    """6x6 covariance (translation, rotation; a left perturbation exp(xi) T) of a rigid fit
    to the pairs src -> dst, from the point-to-point residuals' spread: s^2 (J^T J)^-1 with
    J_i = [I, -[q_i]x] at q_i = R src_i + t."""
    q = src @ R.T + t
    residual = q - dst
    dof = max(3 * len(src) - 6, 1)
    s2 = float(np.sum(residual**2)) / dof
    # sum of J_i^T J_i = [[n I, -[sum q]x], [[sum q]x, sum |q|^2 I - q q^T]]
    a = q.sum(axis=0)
    skew = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    H = np.zeros((6, 6))
    H[:3, :3] = len(src) * np.eye(3)
    H[:3, 3:] = -skew
    H[3:, :3] = skew
    H[3:, 3:] = np.sum(q * q) * np.eye(3) - q.T @ q
    return s2 * np.linalg.inv(H)
