"""Local bundle adjustment (thesis 6.6.4), run by the mapping thread on each new keyframe.

The new keyframe and its covisible keyframes are free, with the converged points they observe;
other keyframes observing those points are fixed (at least two: the monocular gauge includes
scale). Points keep the map's parametrisation, inverse depth along their host keyframe's ray,
and their depth filter's estimate enters as a prior: the filter has folded in every frame since
the point was seeded, while the keyframes see it only two to four times: without the prior, BA
re-triangulated points from those few views, each call moved the local scale a little and
tracking drifted on from the inconsistent map. A free keyframe needs enough observations in the
problem (`ba_min_keyframe_obs`), else it is held: a BA would place it from a handful of points,
worse than tracking did. A BA is skipped when the window already agrees to within
`ba_min_rms_px` (it would only fit noise). A few trust-region iterations (scipy
least_squares with the analytic sparse Jacobian), observations beyond the chi-square 95% bound
(2 dof) dropped, more iterations. The problem is copied under the map lock, solved without
it (tracking goes on; it ends early once a frame waits), and written back under the lock,
where the tracker moves its last frame along with the keyframes (`follow`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.map import CONVERGED, FREE, Map
from vo.se3 import exp_se3, inv_se3, left_jacobian

CHI2_2DOF_95 = 5.991
MIN_FIXED = 2  # fixed keyframes holding the gauge (pose and scale)
MIN_POINTS = 10
# called with each local problem as it is built, map lock held: `sdvl ba-bench` captures them
PROBLEM_OBSERVERS: list[Callable[[Problem, Map], None]] = []


@dataclass
class Problem:
    """A local BA problem: keyframe slots (free first), points and observations."""

    slots: np.ndarray  # keyframe slots, the first n_free are optimised
    n_free: int
    T0: np.ndarray  # (K, 4, 4) T_c_w at the start
    points: np.ndarray  # point ids
    host: np.ndarray  # (M,) index into slots of each point's host keyframe
    f: np.ndarray  # (M, 3) unit bearing of each point in its host
    rho0: np.ndarray  # (M,) inverse depth at the start (the depth filter's)
    prior_w: np.ndarray  # (M,) weight of the depth prior: 1 / (sigma_rho * inflation)
    obs_kf: np.ndarray  # index into slots
    obs_pt: np.ndarray  # index into points
    obs_xy: np.ndarray  # (N, 2) normalised image coordinates
    obs_scale: np.ndarray  # focal / 2^level: errors in pixels at the observation's level
    obs_slot: np.ndarray  # keyframe slot of each observation (identifies it in map.obs)
    # (n_free, 6, 6) square root U of each free keyframe's tracking information (zero:
    # none): the pose prior residuals are U x, x the keyframe's twist away from T0
    pose_sqrt_info: np.ndarray | None = None

    @property
    def n_params(self) -> int:
        """Number of unknowns: 6 per free keyframe, 1 per point."""
        return 6 * self.n_free + len(self.points)

    def rms_px(self) -> float:
        """Root mean square reprojection error (pixels at the observations' levels) at the
        start."""
        e = reprojection_errors(self, self.T0, self.rho0, np.ones(len(self.obs_kf), bool))
        return float(np.sqrt(np.mean(e ** 2)))


def build_problem(map_: Map, slot: int, camera: CameraModel,
                  config: TrackerConfig) -> Problem | None:
    """The local problem around keyframe `slot` (call with the map lock held)."""
    pts, obs = map_.points, map_.obs
    alive_kf = np.array(list(map_.keyframes), dtype=np.int64)
    seen = obs.point[obs.kf == slot]
    free = [slot, *map_.covisible(seen, slot, config.covisible_min_shared)]
    ids = np.unique(obs.point[np.isin(obs.kf, free)])
    ids = ids[(pts.status[ids] == CONVERGED) & np.isin(pts.host[ids], alive_kf)]
    ids = ids[np.bincount(obs.point, minlength=pts.capacity)[ids] >= config.ba_min_views]
    if len(ids) < MIN_POINTS:
        return None
    rows = np.flatnonzero(np.isin(obs.point, ids) & np.isin(obs.kf, alive_kf)
                          & (obs.kf != pts.host[obs.point]))
    # a keyframe the window barely sees is held: tracking placed it from all its matches,
    # a handful of points would re-place it worse
    links = np.bincount(np.concatenate((obs.kf[rows], pts.host[obs.point[rows]])),
                        minlength=len(map_.kf_pyr))
    free = [s for s in free if links[s] >= config.ba_min_keyframe_obs]
    if not free:
        return None
    fixed = sorted((set(obs.kf[rows].tolist()) | set(pts.host[ids].tolist())) - set(free))
    while len(fixed) < MIN_FIXED:
        if len(free) < 2:
            return None
        oldest = min(free, key=lambda s: map_.keyframes[s].id)
        free.remove(oldest)
        fixed.append(oldest)
    slots = np.array(free + fixed, dtype=np.int64)
    index = np.full(len(map_.kf_pyr), -1, np.int64)
    index[slots] = np.arange(len(slots))
    pt_index = np.full(pts.capacity, -1, np.int64)
    pt_index[ids] = np.arange(len(ids))
    f = camera.unproject(obs.uv[rows])
    sqrt_info = (pose_priors([map_.keyframes[s] for s in free], camera)
                 if config.ba_keyframe_prior else None)
    return Problem(
        slots=slots, n_free=len(free), T0=map_.kf_T_c_w[slots].copy(), points=ids,
        host=index[pts.host[ids]], f=pts.f[ids].copy(), rho0=pts.rho[ids].copy(),
        prior_w=1.0 / (config.ba_depth_prior_inflation * pts.sigma[ids]),
        obs_kf=index[obs.kf[rows]], obs_pt=pt_index[obs.point[rows]],
        obs_xy=f[:, :2] / f[:, 2:], obs_scale=np.sqrt(camera.fx * camera.fy)
        / 2.0 ** obs.level[rows], obs_slot=obs.kf[rows].copy(), pose_sqrt_info=sqrt_info)


def pose_priors(keyframes: list, camera: CameraModel) -> np.ndarray:
    """Priors on free keyframes from tracking: (n, 6, 6) square roots of the information of
    each keyframe's tracked pose (all its matches, in BA units: pixels at the match's level,
    unit weight), centred on its current pose. A keyframe without a tracked pose (the
    initial map's) gets none (zeros).

    Why: the BA sees a keyframe only through the converged points with several views, a
    fraction of its matches; without the rest it moved free keyframes along their weakly
    determined tilt-shift direction, away from the truth, even where every observation fit to
    a fraction of a pixel (a few worse matches pulled them). Centred on the current pose, not
    the tracked one: a keyframe a BA moved keeps that move (its map moved with it; centred on
    the tracked pose, kitti00 lost the map)."""
    focal2 = camera.fx * camera.fy
    sqrt_info = np.zeros((len(keyframes), 6, 6))
    for k, kf in enumerate(keyframes):
        if kf.pose_info is None:
            continue
        try:
            sqrt_info[k] = np.linalg.cholesky(kf.pose_info * focal2).T
        except np.linalg.LinAlgError:
            continue
    return sqrt_info


def unpack(p: Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T_c_w of every slot, inverse depth of every point) at parameters x."""
    T = p.T0.copy()
    for k in range(p.n_free):
        T[k] = exp_se3(x[6 * k:6 * k + 6]) @ p.T0[k]
    return T, p.rho0 + x[6 * p.n_free:]


def world_points(p: Problem, T: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """World positions of the points for keyframe poses T and inverse depths rho."""
    T_w = np.array([inv_se3(t) for t in T])[p.host]
    local = p.f / np.maximum(rho, 1e-9)[:, None]
    return np.einsum("nij,nj->ni", T_w[:, :3, :3], local) + T_w[:, :3, 3]


def reprojection_errors(p: Problem, T: np.ndarray, rho: np.ndarray,
                        keep: np.ndarray) -> np.ndarray:
    """(n_kept, 2) reprojection errors in pixels at the observations' levels."""
    P = world_points(p, T, rho)
    kf, pt = p.obs_kf[keep], p.obs_pt[keep]
    X = np.einsum("nij,nj->ni", T[kf, :3, :3], P[pt]) + T[kf, :3, 3]
    z = np.maximum(X[:, 2:], 1e-6)
    return (p.obs_xy[keep] - X[:, :2] / z) * p.obs_scale[keep, None]


def residuals(x: np.ndarray, p: Problem, keep: np.ndarray) -> np.ndarray:
    """Reprojection errors of the kept observations, then the depth priors."""
    T, rho = unpack(p, x)
    return np.concatenate((reprojection_errors(p, T, rho, keep).ravel(),
                           (rho - p.rho0) * p.prior_w, _pose_prior_residuals(p, x)))


def _pose_prior_residuals(p: Problem, x: np.ndarray) -> np.ndarray:
    """U_k x_k of every free keyframe (empty without pose priors)."""
    if p.pose_sqrt_info is None:
        return np.zeros(0)
    twist = x[:6 * p.n_free].reshape(p.n_free, 6)
    return np.einsum("kij,kj->ki", p.pose_sqrt_info, twist).ravel()


def jacobian(x: np.ndarray, p: Problem, keep: np.ndarray) -> csr_matrix:
    """Analytic Jacobian of `residuals` (sparse): each observation's two rows depend on the
    observing and the host keyframe (when free, 6 columns each) and on the point's inverse
    depth; a free keyframe's columns are its twist's, through se3.left_jacobian."""
    T, rho = unpack(p, x)
    kf, pt = p.obs_kf[keep], p.obs_pt[keep]
    host = p.host[pt]
    inv_rho = 1.0 / np.maximum(rho[pt], 1e-9)
    q = p.f[pt] * inv_rho[:, None]  # the point in its host's frame
    R_kh = np.einsum("nij,nkj->nik", T[kf, :3, :3], T[host, :3, :3])  # R_k R_h^T
    X = np.einsum("nij,nj->ni", R_kh, q - T[host, :3, 3]) + T[kf, :3, 3]
    z = np.maximum(X[:, 2], 1e-6)
    # d residual / dX; the residual is (observed - projected) * scale
    A = np.zeros((len(kf), 2, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1.0 / z
    A[:, :, 2] = -X[:, :2] / z[:, None] ** 2
    A *= -p.obs_scale[keep, None, None]
    left = np.array([left_jacobian(x[6 * k:6 * k + 6]) for k in range(p.n_free)])
    eye = np.broadcast_to(np.eye(3), (len(kf), 3, 3))
    # the observing keyframe's left perturbation moves X by (I, -[X]x); the host's moves the
    # point with T_h^-1, so X by -R_k R_h^T (I, -[q]x); the inverse depth by dq = -q / rho
    blocks = [(kf, A @ np.concatenate((eye, -_skew(X)), axis=2)),
              (host, -A @ R_kh @ np.concatenate((eye, -_skew(q)), axis=2))]
    rows = [2 * np.arange(len(kf)) + r for r in (0, 1)]
    cols = [6 * p.n_free + pt] * 2
    d_rho = np.einsum("nij,nj->ni", A @ R_kh, -q * inv_rho[:, None])
    vals = [d_rho[:, 0], d_rho[:, 1]]
    for k, J in blocks:
        on = np.flatnonzero(k < p.n_free)
        J = J[on] @ left[k[on]]
        for r in (0, 1):
            rows.append(np.repeat(2 * on + r, 6))
            cols.append((6 * k[on, None] + np.arange(6)).ravel())
            vals.append(J[:, r].ravel())
    n_points = len(p.points)
    rows.append(2 * len(kf) + np.arange(n_points))
    cols.append(6 * p.n_free + np.arange(n_points))
    vals.append(p.prior_w)
    n_rows = 2 * len(kf) + n_points
    if p.pose_sqrt_info is not None:
        r, c = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
        k = np.arange(p.n_free)[:, None, None]
        rows.append((n_rows + 6 * k + r).ravel())
        cols.append((6 * k + c).ravel())
        vals.append(p.pose_sqrt_info.ravel())
        n_rows += 6 * p.n_free
    return csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n_rows, p.n_params))


def _skew(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3) cross-product matrices of the rows of v."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def solve(p: Problem, first: int = 5, second: int = 10, method: str = "trf",
          stop: Callable[[], bool] = lambda: False, pause: Callable[[], None] = lambda: None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Optimise: `first` iterations, drop chi2(2 dof, 95%) outliers (1 px sigma), `second`
    more. Returns (T_c_w of the slots, inverse depths, kept-observation mask). `method` is
    scipy's: 'trf' or 'dogbox' (sparse), 'lm' (MINPACK, dense), or 'gtsam' (vo.ba_gtsam:
    Levenberg-Marquardt on a factor graph, same residuals). Once `stop()` says so (a
    frame waits for the mapping thread), the BA ends after the current iteration ('lm': the
    current round) with the best parameters so far. `pause()` is called before each
    evaluation of the residuals: a tracker holds the BA there while it tracks a frame (the
    solver's Python code would take the GIL from it)."""
    if method == "gtsam":
        from vo.ba_gtsam import solve_gtsam

        return solve_gtsam(p, first, second, stop, pause, inliers)
    x = np.zeros(p.n_params)
    keep = np.ones(len(p.obs_kf), dtype=bool)

    def check(_x: np.ndarray) -> None:
        if stop():
            raise StopIteration

    for rounds, drop in ((first, True), (second, False)):
        if rounds <= 0 or keep.sum() < 6 or stop():
            break
        start = np.sum(residuals(x, p, keep) ** 2)
        if method == "lm":
            options = {"jac": _dense(jacobian)}
        else:
            options = {"jac": jacobian, "x_scale": "jac", "callback": check}
        res = least_squares(_paused(pause, residuals), x, method=method, args=(p, keep),
                            max_nfev=rounds, **options)
        if np.sum(res.fun ** 2) < start:
            x = res.x
        if drop:
            keep = inliers(p, *unpack(p, x))
    T, rho = unpack(p, x)
    return T, rho, keep


def inliers(p: Problem, T: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Mask of the observations within the chi-square 95% bound (2 dof, 1 px sigma) at
    keyframe poses T and inverse depths rho."""
    e = reprojection_errors(p, T, rho, np.ones(len(p.obs_kf), dtype=bool))
    return (e ** 2).sum(axis=1) < CHI2_2DOF_95


def cost(p: Problem, T: np.ndarray, rho: np.ndarray, keep: np.ndarray) -> float:
    """Half the sum of squared residuals (kept reprojection errors, depth and pose priors) at
    keyframe poses T and inverse depths rho, whichever solver found them."""
    x = np.concatenate([log_se3(T[k] @ inv_se3(p.T0[k])) for k in range(p.n_free)]
                       + [rho - p.rho0])
    return 0.5 * float(np.sum(residuals(x, p, keep) ** 2))


def truncated_cost(p: Problem, T: np.ndarray, rho: np.ndarray) -> float:
    """The cost with every observation's squared error capped at the chi-square bound (the
    robust kernel the outlier cut stands for): comparable between solutions whatever each
    solver dropped."""
    keep = inliers(p, T, rho)
    return cost(p, T, rho, keep) + 0.5 * CHI2_2DOF_95 * float(np.sum(~keep))


def log_se3(T: np.ndarray) -> np.ndarray:
    """The twist (v, w) with exp_se3(twist) = T."""
    w = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    theta = float(np.linalg.norm(w))
    W = _skew(w[None])[0]
    if theta < 1e-8:
        V_inv = np.eye(3) - 0.5 * W
    else:
        half = 0.5 * theta
        V_inv = (np.eye(3) - 0.5 * W
                 + (1.0 - half * np.cos(half) / np.sin(half)) / theta ** 2 * (W @ W))
    return np.concatenate((V_inv @ T[:3, 3], w))


def _paused(pause: Callable[[], None], fun: Callable) -> Callable:
    """fun, calling pause() first."""
    def paused(*args):
        pause()
        return fun(*args)
    return paused


def _dense(fun: Callable) -> Callable:
    """fun with its sparse result as a dense array (MINPACK's 'lm' takes only those)."""
    def dense(*args):
        return fun(*args).toarray()
    return dense


def apply(map_: Map, p: Problem, T: np.ndarray, rho: np.ndarray,
          keep: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Write an optimised problem back (call with the map lock held): keyframe poses, the
    points' inverse depths, the positions of everything the moved keyframes host; outlier
    observations are forgotten. Returns the moved keyframes: slot -> (T_c_w before, after)."""
    pts = map_.points
    moved = {}
    for k, slot in enumerate(p.slots[:p.n_free]):
        if int(slot) in map_.keyframes:
            moved[int(slot)] = (map_.kf_T_c_w[slot].copy(), T[k].copy())
            map_.kf_T_c_w[slot] = T[k]
            map_.keyframes[int(slot)].T_c_w = T[k].copy()
    ok = (pts.status[p.points] == CONVERGED) & (rho > 0)
    pts.rho[p.points[ok]] = rho[ok]
    for slot in set(moved) | set(p.slots[p.host[ok]].tolist()):
        if slot in map_.keyframes:
            hosted = np.flatnonzero((pts.host == slot) & (pts.status != FREE))
            pts.update_positions(hosted, inv_se3(map_.kf_T_c_w[slot]))
    if not keep.all():
        # by (point, keyframe): rows may have moved while the problem was solved
        n = len(map_.kf_pyr)
        bad = p.points[p.obs_pt[~keep]] * n + p.obs_slot[~keep]
        map_.obs.keep(~np.isin(map_.obs.point * n + map_.obs.kf, bad))
    return moved


def follow(T_c_w: np.ndarray, point_ids: np.ndarray, map_: Map,
           moved: dict[int, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The pose of a frame tracked before a BA moved keyframes (`moved` as apply returns),
    moved along with the moved keyframe that observes most of its points `point_ids`, the
    newest of equals (its pose relative to that keyframe is kept); unchanged when none does.
    Call with the map lock held."""
    obs = map_.obs
    seen = np.concatenate((obs.kf[np.isin(obs.point, point_ids)], map_.points.host[point_ids]))
    shared = np.bincount(seen, minlength=len(map_.kf_pyr))
    ref = max(moved, default=None, key=lambda s: (shared[s], map_.keyframes[s].id))
    if ref is None or shared[ref] == 0:
        return T_c_w
    T_old, T_new = moved[ref]
    return T_c_w @ inv_se3(T_old) @ T_new


def local_ba(map_: Map, slot: int, camera: CameraModel, config: TrackerConfig,
             stop: Callable[[], bool] = lambda: False,
             moved_keyframes: Callable[[dict], None] = lambda moved: None,
             pause: Callable[[], None] = lambda: None) -> int:
    """Run local BA around keyframe `slot`; returns the number of observations used. `stop`
    and `pause` as for solve; `moved_keyframes` gets apply's result while the map lock is
    still held (a tracker moves its last pose along before it tracks against the new map)."""
    with map_.lock:
        problem = build_problem(map_, slot, camera, config)
        for observe in PROBLEM_OBSERVERS if problem is not None else ():
            observe(problem, map_)
    if problem is None:
        return 0
    if problem.rms_px() < config.ba_min_rms_px:
        return 0  # already consistent to within the noise: nothing to gain
    T, rho, keep = solve(problem, config.ba_first_iterations, config.ba_second_iterations,
                         config.ba_method, stop, pause)
    with map_.lock:
        moved_keyframes(apply(map_, problem, T, rho, keep))
    return int(keep.sum())
