"""Outlier rejection (thesis 6.8): RANSAC over random 5-point subsets of a frame's matches, each
hypothesis a Gauss-Newton update of the prior pose from its subset only; inliers by reprojection
error; the number of hypotheses adapts to the best inlier ratio (p = 0.99, at most a cap).

A hypothesis is fitted with the pose optimiser's weights (each match scaled down by its pyramid
level), but inliers are judged by the reprojection error in the image, as the thesis says:
thresholds are image pixels divided by the focal length. Judged at the match's level, a 2 px
threshold let 8 px through at level 2, and people mapped while they stood kept passing as
inliers as they walked off.

Each error is whitened by a 2x2 matrix per match: identity by default, or (config
ransac_depth_whitening) the pose optimiser's depth whitening (pose_optimizer.depth_whitening),
under which a point whose depth the filter has not yet narrowed may lie anywhere along its
epipolar segment and only its error across the segment is held to the threshold in full.
"""

from __future__ import annotations

import numba
import numpy as np

from vo.normal_equations import solve_spd
from vo.se3 import compose_into, exp_se3_into, plane_jacobian, transform

SUBSET = 5
HYPOTHESIS_ITERATIONS = 5


@numba.njit(cache=True, nogil=True)
def _squared_error(pos_w, obs, whiten, T_c_w, i):
    """Match i's squared reprojection error (normalised plane) at T_c_w, whitened by its 2x2
    matrix (inf behind the camera)."""
    X, Y, Z = transform(T_c_w, pos_w[i, 0], pos_w[i, 1], pos_w[i, 2])
    if Z <= 1e-9:
        return np.inf
    ex = obs[i, 0] - X / Z
    ey = obs[i, 1] - Y / Z
    W = whiten[i]
    wx = W[0, 0] * ex + W[0, 1] * ey
    wy = W[1, 0] * ex + W[1, 1] * ey
    return wx * wx + wy * wy


@numba.njit(cache=True, nogil=True)
def squared_errors(pos_w, obs, whiten, T_c_w):
    """Per match the squared whitened reprojection error (normalised plane) at T_c_w (inf
    behind the camera)."""
    out = np.empty(pos_w.shape[0])
    for i in range(pos_w.shape[0]):
        out[i] = _squared_error(pos_w, obs, whiten, T_c_w, i)
    return out


@numba.njit(cache=True, nogil=True)
def fit_subset(pos_w, obs, scale, subset, T_prior, iterations, work):
    """T_prior updated by plain Gauss-Newton on the matches `subset` only, in work[0] (`work`:
    the buffers of fit_buffers, reused over a RANSAC's hypotheses)."""
    T, step, stepped, H, b, J = work
    T[:, :] = T_prior
    for _ in range(iterations):
        H[:, :] = 0.0
        for a in range(6):
            H[a, a] = 1e-12
        b[:] = 0.0
        for i in subset:
            X, Y, Z = transform(T, pos_w[i, 0], pos_w[i, 1], pos_w[i, 2])
            if Z <= 1e-9:
                continue
            plane_jacobian(X, Y, Z, J)
            s = scale[i]
            ex = (obs[i, 0] - X / Z) * s
            ey = (obs[i, 1] - Y / Z) * s
            for a in range(6):
                b[a] += s * (J[0, a] * ex + J[1, a] * ey)
                for q in range(a, 6):  # the upper triangle, mirrored below
                    H[a, q] += s * s * (J[0, a] * J[0, q] + J[1, a] * J[1, q])
        for a in range(1, 6):
            for q in range(a):
                H[a, q] = H[q, a]
        det, xi = solve_spd(H, b)
        if det == 0.0:  # a degenerate subset: no fit
            break
        exp_se3_into(xi, step)
        compose_into(step, T, stepped)
        T[:, :] = stepped
        if np.sqrt(xi @ xi) < 1e-12:
            break
    return T


@numba.njit(cache=True, nogil=True)
def fit_buffers():
    """The work buffers of fit_subset: pose, step, stepped pose, normal matrix and vector,
    Jacobian."""
    return (np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4)), np.empty((6, 6)),
            np.empty(6), np.zeros((2, 6)))


@numba.njit(cache=True, nogil=True)
def count_within(pos_w, obs, whiten, T_c_w, thr2, enough):
    """How many matches reproject within sqrt(thr2) (normalised plane, whitened) at T_c_w, or
    -1 as soon as fewer than `enough` can (a hypothesis that cannot beat the best is not scored
    to the end)."""
    n = pos_w.shape[0]
    count = 0
    for i in range(n):
        if _squared_error(pos_w, obs, whiten, T_c_w, i) < thr2:
            count += 1
        if count + n - 1 - i < enough:
            return -1
    return count


@numba.njit(cache=True, nogil=True)
def hypotheses_needed(n_inliers, n, p, cap):
    """Eq. 6.12: hypotheses for probability p of one outlier-free subset, at most cap."""
    w = (n_inliers / n) ** SUBSET
    if w >= 1.0:
        return 1
    if w <= 0.0:
        return cap
    return min(cap, int(np.ceil(np.log(1.0 - p) / np.log(1.0 - w))))


def ransac(pos_w, obs, whiten, scale, T_prior, draw, threshold, p, cap, T_first):
    """Inlier mask of the best hypothesis, T_first (a pose fitted to all matches) or one fitted
    to a row of `draw(k)` (k rows of SUBSET match indices), and the number of rows tried;
    errors whitened by `whiten` (N, 2, 2). As
    many rows are drawn as eq. 6.12 asks after T_first (at most `cap`): better hypotheses only
    lower that number, so they are all there is to try (vamr needs 8 at the median; drawing
    all of the cap cost 0.2 ms a frame)."""
    thr2 = threshold * threshold
    best = squared_errors(pos_w, obs, whiten, T_first) < thr2
    needed = hypotheses_needed(best.sum(), pos_w.shape[0], p, cap)
    return _try_subsets(pos_w, obs, whiten, scale, T_prior, draw(needed), thr2, p, cap, best)


@numba.njit(cache=True, nogil=True)
def _try_subsets(pos_w, obs, whiten, scale, T_prior, subsets, thr2, p, cap, best):
    """RANSAC's loop over the rows of `subsets` while eq. 6.12 still asks for hypotheses,
    from the inlier mask `best`: the best mask and the number of rows tried."""
    n = pos_w.shape[0]
    best_count = best.sum()
    needed = subsets.shape[0]
    tried = 0
    work = fit_buffers()
    while tried < needed:
        T = fit_subset(pos_w, obs, scale, subsets[tried], T_prior, HYPOTHESIS_ITERATIONS, work)
        tried += 1
        count = count_within(pos_w, obs, whiten, T, thr2, best_count + 1)
        if count > best_count:
            best, best_count = squared_errors(pos_w, obs, whiten, T) < thr2, count
            needed = min(needed, hypotheses_needed(count, n, p, cap))
    return best, tried


def random_subsets(n: int, count: int, seed: int) -> np.ndarray:
    """`count` rows of SUBSET distinct match indices in 0..n-1, from a seeded generator: each
    row the positions of the SUBSET smallest of n uniform draws (a random subset). The first k
    rows do not depend on `count`."""
    return _smallest(np.random.default_rng(seed).random((count, n)), SUBSET)


@numba.njit(cache=True, nogil=True)
def _smallest(values, k):
    """Per row of values, the indices of its k smallest entries, smallest first."""
    out = np.empty((values.shape[0], k), dtype=np.int64)
    for r in range(values.shape[0]):
        row = values[r]
        for j in range(k):  # insertion into the sorted first j
            out[r, j] = j
            i = j
            while i > 0 and row[out[r, i - 1]] > row[out[r, i]]:
                out[r, i - 1], out[r, i] = out[r, i], out[r, i - 1]
                i -= 1
        for c in range(k, row.shape[0]):
            if row[c] >= row[out[r, k - 1]]:
                continue
            i = k - 1
            while i > 0 and row[out[r, i - 1]] > row[c]:
                out[r, i] = out[r, i - 1]
                i -= 1
            out[r, i] = c
    return out
