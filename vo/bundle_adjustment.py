"""Local bundle adjustment (thesis 6.6.4), run by the mapping thread on each new keyframe.

The new keyframe and its covisible keyframes are free, with the converged points they observe;
other keyframes observing those points are fixed. Levenberg-Marquardt-like trust-region steps
(scipy least_squares, 'trf' with a sparse Jacobian pattern): a few iterations, observations
beyond the chi-square 95% bound (2 dof) dropped, more iterations. The problem is copied under
the map lock, solved without it (tracking goes on), and written back under the lock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.map import CONVERGED, FREE, Map
from vo.se3 import exp_se3, inv_se3

CHI2_2DOF_95 = 5.991
MIN_VIEWS = 2  # keyframes observing a point besides its host


@dataclass
class Problem:
    """A local BA problem: keyframe slots (free first), points and observations."""

    slots: np.ndarray  # keyframe slots, the first n_free are optimised
    n_free: int
    T0: np.ndarray  # (K, 4, 4) T_c_w at the start
    points: np.ndarray  # point ids
    P0: np.ndarray  # (M, 3) world positions at the start
    obs_kf: np.ndarray  # index into slots
    obs_pt: np.ndarray  # index into points
    obs_xy: np.ndarray  # (N, 2) normalised image coordinates
    obs_scale: np.ndarray  # focal / 2^level: errors in pixels at the observation's level
    obs_row: np.ndarray  # row in map.obs, -1 for a host observation


def build_problem(map_: Map, slot: int, camera: CameraModel,
                  config: TrackerConfig) -> Problem | None:
    """The local problem around keyframe `slot` (call with the map lock held)."""
    pts, obs = map_.points, map_.obs
    seen = obs.point[obs.kf == slot]
    free = [slot, *map_.covisible(seen, slot, config.covisible_min_shared)]
    ids = np.unique(obs.point[np.isin(obs.kf, free)])
    ids = ids[pts.status[ids] == CONVERGED]
    # a point seen by one keyframe besides its host has a poorly constrained depth
    ids = ids[np.bincount(obs.point, minlength=pts.capacity)[ids] >= MIN_VIEWS]
    if len(ids) < 10:
        return None
    rows = np.flatnonzero(np.isin(obs.point, ids) & np.isin(obs.kf, list(map_.keyframes)))
    hosted = ids[np.isin(pts.host[ids], list(map_.keyframes))]
    fixed = sorted((set(obs.kf[rows].tolist()) | set(pts.host[hosted].tolist())) - set(free))
    if not fixed:
        # monocular gauge: keep the oldest keyframe of the window in place
        oldest = min(free, key=lambda s: map_.keyframes[s].id)
        free.remove(oldest)
        fixed = [oldest]
        if not free:
            return None
    slots = np.array(free + fixed, dtype=np.int64)
    index = {int(s): k for k, s in enumerate(slots)}
    pt_index = np.full(pts.capacity, -1, np.int64)
    pt_index[ids] = np.arange(len(ids))
    uv = np.vstack((obs.uv[rows], np.column_stack((pts.u[hosted], pts.v[hosted]))))
    level = np.concatenate((obs.level[rows], pts.level[hosted]))
    f = camera.unproject(uv)
    return Problem(
        slots=slots, n_free=len(free), T0=map_.kf_T_c_w[slots].copy(), points=ids,
        P0=pts.pos_w[ids].copy(),
        obs_kf=np.array([index[int(s)] for s in np.concatenate((obs.kf[rows], pts.host[hosted]))],
                        dtype=np.int64),
        obs_pt=pt_index[np.concatenate((obs.point[rows], hosted))],
        obs_xy=f[:, :2] / f[:, 2:], obs_scale=np.sqrt(camera.fx * camera.fy) / 2.0 ** level,
        obs_row=np.concatenate((rows, np.full(len(hosted), -1))))


def _unpack(p: Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T = p.T0.copy()
    for k in range(p.n_free):
        T[k] = exp_se3(x[6 * k:6 * k + 6]) @ p.T0[k]
    return T, x[6 * p.n_free:].reshape(-1, 3)


def _residuals(x: np.ndarray, p: Problem, keep: np.ndarray) -> np.ndarray:
    T, P = _unpack(p, x)
    kf, pt = p.obs_kf[keep], p.obs_pt[keep]
    X = np.einsum("nij,nj->ni", T[kf, :3, :3], P[pt]) + T[kf, :3, 3]
    z = np.maximum(X[:, 2:], 1e-6)
    e = (p.obs_xy[keep] - X[:, :2] / z) * p.obs_scale[keep, None]
    return e.ravel()


def _sparsity(p: Problem, keep: np.ndarray) -> lil_matrix:
    n_obs = int(keep.sum())
    n_par = 6 * p.n_free + 3 * len(p.points)
    A = lil_matrix((2 * n_obs, n_par), dtype=np.int8)
    rows = np.arange(n_obs)
    kf, pt = p.obs_kf[keep], p.obs_pt[keep]
    for r in (0, 1):
        for c in range(3):
            A[2 * rows + r, 6 * p.n_free + 3 * pt + c] = 1
        on_free = kf < p.n_free
        for c in range(6):
            A[2 * rows[on_free] + r, 6 * kf[on_free] + c] = 1
    return A


def solve(p: Problem, first: int = 5, second: int = 10) -> tuple[np.ndarray, np.ndarray,
                                                                    np.ndarray]:
    """Optimise: `first` iterations, drop chi2(2 dof, 95%) outliers (1 px sigma), `second`
    more. Returns (T_c_w of the slots, point positions, kept-observation mask)."""
    x = np.concatenate((np.zeros(6 * p.n_free), p.P0.ravel()))
    keep = np.ones(len(p.obs_kf), dtype=bool)
    for rounds, drop in ((first, True), (second, False)):
        if rounds <= 0 or keep.sum() < 6:
            break
        start = 0.5 * np.sum(_residuals(x, p, keep) ** 2)
        res = least_squares(_residuals, x, jac_sparsity=_sparsity(p, keep), method="trf",
                            max_nfev=rounds, x_scale="jac", args=(p, keep))
        if 0.5 * np.sum(res.fun ** 2) < start:
            x = res.x
        if drop:
            e = _residuals(x, p, np.ones_like(keep)).reshape(-1, 2)
            keep = (e ** 2).sum(axis=1) < CHI2_2DOF_95
    T, P = _unpack(p, x)
    return T, P, keep


def apply(map_: Map, p: Problem, T: np.ndarray, P: np.ndarray, keep: np.ndarray) -> None:
    """Write an optimised problem back (call with the map lock held): keyframe poses, the
    free points' inverse depths along their host rays, the positions of everything the moved
    keyframes host; outlier observations are forgotten."""
    pts = map_.points
    alive = [int(s) for s in p.slots[:p.n_free] if int(s) in map_.keyframes]
    for k, slot in enumerate(p.slots[:p.n_free]):
        if int(slot) in map_.keyframes:
            map_.kf_T_c_w[slot] = T[k]
            map_.keyframes[int(slot)].T_c_w = T[k].copy()
    ok = pts.status[p.points] == CONVERGED
    ids, P = p.points[ok], P[ok]
    hosts = set(alive)
    for slot in np.unique(pts.host[ids]):
        sel = pts.host[ids] == slot
        T_h = map_.kf_T_c_w[slot]
        X = P[sel] @ T_h[:3, :3].T + T_h[:3, 3]
        depth = np.einsum("ij,ij->i", X, pts.f[ids[sel]])
        good = depth > 1e-6
        pts.rho[ids[sel][good]] = 1.0 / depth[good]
        hosts.add(int(slot))
    for slot in hosts:
        hosted = np.flatnonzero((pts.host == slot) & (pts.status != FREE))
        pts.update_positions(hosted, inv_se3(map_.kf_T_c_w[slot]))
    bad_rows = p.obs_row[~keep & (p.obs_row >= 0)]
    if len(bad_rows):
        mask = np.ones(len(map_.obs), dtype=bool)
        mask[bad_rows] = False
        map_.obs.keep(mask)


def local_ba(map_: Map, slot: int, camera: CameraModel, config: TrackerConfig) -> int:
    """Run local BA around keyframe `slot`; returns the number of observations used."""
    with map_.lock:
        problem = build_problem(map_, slot, camera, config)
    if problem is None:
        return 0
    T, P, keep = solve(problem, config.ba_first_iterations, config.ba_second_iterations)
    with map_.lock:
        apply(map_, problem, T, P, keep)
    return int(keep.sum())
