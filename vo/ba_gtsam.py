"""The local BA problem of vo.bundle_adjustment solved with GTSAM (gtsam.org, Dellaert and
Kaess, "Factor Graphs for Robot Perception" 2017): Levenberg-Marquardt over a factor graph
with the same residuals as the scipy path: per point one factor with the reprojection errors
(pixels at the observation's level) of its kept observations, a prior on its inverse depth,
and on each free keyframe the tracking prior; the fixed keyframes are constants.

GTSAM has no factor for a point parametrised by its inverse depth along a fixed bearing of its
host keyframe, so that factor is a gtsam.CustomFactor (Python) with analytic Jacobians in
GTSAM's tangent space of Pose3 (rotation first, perturbation on the right: T exp(xi)).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sdvl.errors import InputError
from vo.config import GTSAM_MISSING
from vo.se3 import adjoint, skew

RELATIVE_TOL = 1e-6  # an LM iteration that lowers the cost less than this fraction ends a round
SWAP = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])  # (w,v)<->(v,w)


def import_gtsam():
    """The gtsam module, or an InputError saying how to install it."""
    try:
        import gtsam
    except ImportError as exc:
        raise InputError(GTSAM_MISSING) from exc
    return gtsam


def solve_gtsam(p, first: int, second: int, stop: Callable[[], bool],
                pause: Callable[[], None], inliers: Callable
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Like bundle_adjustment.solve: `first` LM iterations, the observations `inliers(p, T,
    rho)` rejects dropped, `second` more; `stop` ends it after the current iteration, `pause`
    is called before each. Returns (T_c_w of the slots, inverse depths, kept mask)."""
    gtsam = import_gtsam()
    keep = np.ones(len(p.obs_kf), dtype=bool)
    values = gtsam.Values()
    for k in range(p.n_free):
        values.insert(_pose_key(gtsam, k), gtsam.Pose3(p.T0[k]))
    for j, rho in enumerate(p.rho0):
        values.insert(_rho_key(gtsam, j), np.array([rho]))
    for rounds, drop in ((first, True), (second, False)):
        if rounds <= 0 or keep.sum() < 6 or stop():
            break
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(rounds)
        optimizer = gtsam.LevenbergMarquardtOptimizer(_graph(gtsam, p, keep), values, params)
        for _ in range(rounds):
            pause()
            before = optimizer.error()
            optimizer.iterate()
            if stop() or before - optimizer.error() < RELATIVE_TOL * before:
                break
        values = optimizer.values()
        if drop:
            keep = inliers(p, *_unpack(gtsam, p, values))
    T, rho = _unpack(gtsam, p, values)
    return T, rho, keep


def _pose_key(gtsam, k: int) -> int:
    return gtsam.symbol("x", k)


def _rho_key(gtsam, j: int) -> int:
    return gtsam.symbol("r", j)


def _unpack(gtsam, p, values) -> tuple[np.ndarray, np.ndarray]:
    """(T_c_w of every slot, inverse depth of every point) in `values`."""
    T = p.T0.copy()
    for k in range(p.n_free):
        T[k] = values.atPose3(_pose_key(gtsam, k)).matrix()
    rho = np.array([values.atVector(_rho_key(gtsam, j))[0] for j in range(len(p.points))])
    return T, rho


def _graph(gtsam, p, keep: np.ndarray):
    """The factor graph of the problem with the observations `keep`."""
    graph = gtsam.NonlinearFactorGraph()
    pt = p.obs_pt[keep]
    order = np.argsort(pt, kind="stable")
    starts = np.searchsorted(pt[order], np.arange(len(p.points) + 1))
    rows = np.flatnonzero(keep)[order]
    for j in range(len(p.points)):
        graph.add(gtsam.PriorFactorVector(_rho_key(gtsam, j), p.rho0[j:j + 1],
                                          gtsam.noiseModel.Isotropic.Sigma(1, 1 / p.prior_w[j])))
        mine = rows[starts[j]:starts[j + 1]]
        if len(mine):
            graph.add(_point_factor(gtsam, p, j, mine))
    for k in range(p.n_free):
        U = None if p.pose_sqrt_info is None else p.pose_sqrt_info[k]
        if U is not None and U.any():
            # the scipy path's U x, x = log(T T0^-1) = Ad(T0) log(T0^-1 T), GTSAM's local
            # coordinates of T at T0 in (w, v) order
            noise = gtsam.noiseModel.Gaussian.SqrtInformation(U @ adjoint(p.T0[k]) @ SWAP)
            graph.add(gtsam.PriorFactorPose3(_pose_key(gtsam, k), gtsam.Pose3(p.T0[k]), noise))
    return graph


def _point_factor(gtsam, p, j: int, rows: np.ndarray):
    """The reprojection errors of point j in the observations `rows` (a CustomFactor on its
    inverse depth and on its free host and observing keyframes)."""
    host = int(p.host[j])
    observers = p.obs_kf[rows]
    free = sorted({s for s in (host, *observers.tolist()) if s < p.n_free})
    keys = [_rho_key(gtsam, j)] + [_pose_key(gtsam, s) for s in free]
    column = {s: i + 1 for i, s in enumerate(free)}
    xy, scale, f = p.obs_xy[rows], p.obs_scale[rows], p.f[j]

    def error(this, values, H):
        T = {s: values.atPose3(_pose_key(gtsam, s)).matrix() for s in free}
        T_h = T.get(host, p.T0[host])
        T_k = np.array([T.get(s, p.T0[s]) for s in observers.tolist()])
        rho = values.atVector(keys[0])[0]
        e, jac = point_residuals(T_h, T_k, f, rho, xy, scale)
        if H is not None:
            d_rho, d_obs, d_host = jac
            H[0] = d_rho[:, None]
            for s in free:
                J = np.zeros((2 * len(rows), 6))
                if s == host:
                    J += d_host
                mine = np.repeat(observers == s, 2)
                J[mine] += d_obs[mine]
                H[column[s]] = J
        return e

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2 * len(rows)), keys, error)


def point_residuals(T_h: np.ndarray, T_k: np.ndarray, f: np.ndarray, rho: float,
                    xy: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, tuple]:
    """Reprojection errors (2n,) of a point at inverse depth rho along bearing f of its host
    T_h (T_c_w) seen by the keyframes T_k (n, 4, 4) at normalised xy, in pixels (`scale`);
    and their Jacobians: by rho (2n,), by each observer's and by the host's right
    perturbation in GTSAM's order (w, v) (2n, 6)."""
    q = f / max(rho, 1e-9)  # the point in its host's frame
    P = T_h[:3, :3].T @ (q - T_h[:3, 3])
    R = T_k[:, :3, :3]
    X = R @ P + T_k[:, :3, 3]
    z = np.maximum(X[:, 2], 1e-6)
    e = ((xy - X[:, :2] / z[:, None]) * scale[:, None]).ravel()
    A = np.zeros((len(z), 2, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1.0 / z
    A[:, :, 2] = -X[:, :2] / z[:, None] ** 2
    A *= -scale[:, None, None]
    AR = A @ R
    d_rho = AR @ (T_h[:3, :3].T @ (-q / max(rho, 1e-9)))
    P_x = skew(np.ascontiguousarray(P))
    # T_k exp(xi) moves X by R_k (-[P]x w + v); T_h exp(xi) moves P by [P]x w - v
    d_obs = np.concatenate((AR @ -P_x, AR), axis=2)
    d_host = np.concatenate((AR @ P_x, -AR), axis=2)
    return e, (d_rho.ravel(), d_obs.reshape(-1, 6), d_host.reshape(-1, 6))

