"""Local bundle adjustment (thesis 6.6.4): free keyframes and inverse depths recover from a
perturbation with fixed keyframes holding the gauge; the depth prior holds a point that the
views barely constrain; gross outliers are cut by the chi-square test; every solver gives the
same answer; the analytic Jacobians match central differences."""

from __future__ import annotations

import numpy as np
import pytest

from calib.camera import CameraModel
from vo import bundle_adjustment as ba
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.map import CONVERGED, Map
from vo.se3 import exp_se3, inv_se3, left_jacobian, plane_jacobian
from vo.tracker import Tracker

FOCAL = 400.0


def _problem(rng, n_points=60, outliers=0, sigma_rho=0.02):
    """Four keyframes looking at points 3-5 m ahead; the first two free, the last two fixed;
    points hosted by keyframe 0 (free) and 2 (fixed), seen by the other three."""
    T_true = np.array([exp_se3(np.array([0.3 * k, 0.05 * k, 0.0, 0.01 * k, -0.02 * k, 0.0]))
                       for k in range(4)])
    host = np.where(np.arange(n_points) % 2 == 0, 0, 2)
    local = np.column_stack([rng.uniform(-2, 2, n_points), rng.uniform(-1.5, 1.5, n_points),
                             rng.uniform(3, 5, n_points)])
    depth = np.linalg.norm(local, axis=1)
    f = local / depth[:, None]
    T_w = np.array([inv_se3(T_true[h]) for h in host])
    P_true = np.einsum("nij,nj->ni", T_w[:, :3, :3], local) + T_w[:, :3, 3]
    kf = np.repeat(np.arange(4), n_points)
    pt = np.tile(np.arange(n_points), 4)
    seen = kf != host[pt]
    kf, pt = kf[seen], pt[seen]
    X = np.einsum("nij,nj->ni", T_true[kf, :3, :3], P_true[pt]) + T_true[kf, :3, 3]
    xy = X[:, :2] / X[:, 2:] + rng.normal(0, 0.5 / FOCAL, (len(kf), 2))
    bad = rng.choice(len(kf), outliers, replace=False)
    xy[bad] += 30.0 / FOCAL
    T0 = T_true.copy()
    for k in range(2):
        T0[k] = exp_se3(rng.normal(0, 0.01, 6)) @ T_true[k]
    rho0 = 1.0 / depth * (1.0 + rng.normal(0, sigma_rho, n_points))
    p = ba.Problem(slots=np.arange(4), n_free=2, T0=T0, points=np.arange(n_points), host=host,
                   f=f, rho0=rho0, prior_w=1.0 / (sigma_rho / depth), obs_kf=kf, obs_pt=pt,
                   obs_xy=xy, obs_scale=np.full(len(kf), FOCAL), obs_slot=kf.copy())
    return p, T_true, 1.0 / depth, bad


def _rms(p, T, rho, keep=None):
    keep = np.ones(len(p.obs_kf), bool) if keep is None else keep
    return np.sqrt(np.mean(ba.reprojection_errors(p, T, rho, keep) ** 2))


def _central_differences(fun, x, h=1e-6):
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((fun(x + e) - fun(x - e)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("size", [1e-4, 0.05, 1.5])
def test_left_jacobian_maps_a_twist_step_to_a_left_perturbation(size):
    """exp(xi + d) = exp(J d) exp(xi): on both sides of the series/closed-form switch."""
    xi = np.random.default_rng(7).normal(0, size, 6)

    def left_twist(x):  # the twist of exp(x) exp(xi)^-1, to first order near xi
        D = exp_se3(x) @ inv_se3(exp_se3(xi))
        return np.concatenate((D[:3, 3], [D[2, 1], D[0, 2], D[1, 0]]))

    np.testing.assert_allclose(left_jacobian(xi), _central_differences(left_twist, xi),
                               atol=1e-8)
    assert np.allclose(left_jacobian(np.zeros(6)), np.eye(6))


def test_jacobian_matches_central_differences():
    """Away from the start (keyframes moved, depths changed) and with observations dropped."""
    p, _, _, _ = _problem(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    x = rng.normal(0, 0.05, p.n_params)
    x[6 * p.n_free:] *= 0.01
    keep = rng.random(len(p.obs_kf)) > 0.2
    J = ba.jacobian(x, p, keep)
    numeric = _central_differences(lambda y: ba.residuals(y, p, keep), x)
    assert J.shape == numeric.shape
    np.testing.assert_allclose(J.toarray(), numeric, atol=1e-6 * np.abs(numeric).max())
    # sparse: per observation row 6 columns per free keyframe involved and one inverse depth
    assert J.nnz <= 2 * keep.sum() * 13 + len(p.points)


def test_jacobian_with_pose_priors_matches_central_differences():
    p, _, _, _ = _problem(np.random.default_rng(0))
    rng = np.random.default_rng(2)
    U = np.triu(rng.normal(0, 50.0, (p.n_free, 6, 6)))
    p = ba.Problem(**{**p.__dict__, "pose_sqrt_info": U})
    x = rng.normal(0, 0.05, p.n_params)
    keep = np.ones(len(p.obs_kf), bool)
    J = ba.jacobian(x, p, keep)
    numeric = _central_differences(lambda y: ba.residuals(y, p, keep), x)
    np.testing.assert_allclose(J.toarray(), numeric, atol=1e-6 * np.abs(numeric).max())


def _tracking_information(T_c_w: np.ndarray, P: np.ndarray) -> np.ndarray:
    """J^T J of a pose (normalised plane, unit weight) tracked from world points P."""
    X = P @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    J = np.zeros((2, 6))
    H = np.zeros((6, 6))
    for x, y, z in X:
        plane_jacobian(x, y, z, J)
        H += J.T @ J
    return H


def test_a_tracked_keyframe_seen_through_few_points_keeps_its_pose():
    """A keyframe tracking placed well from all its matches, which the window sees through a
    few points (one matched 2 px off, inside the chi-square bound): alone, those few points
    pull it off; with its tracking information as a prior it stays (survey-down: free
    keyframes moved 0.01 -> 0.1 m, 0.1 -> 0.5 deg without)."""
    rng = np.random.default_rng(4)
    p, T_true, _, _ = _problem(rng, n_points=60)
    T0 = p.T0.copy()
    T0[0] = T_true[0]  # tracking had it right
    P = ba.world_points(p, T_true, p.rho0)  # the map points it was tracked from
    few = (p.obs_kf != 0) | (p.obs_pt < 12)
    xy = p.obs_xy.copy()
    xy[np.flatnonzero((p.obs_kf == 0) & few)[0]] += 2.0 / FOCAL
    base = {**p.__dict__, "T0": T0, "obs_kf": p.obs_kf[few], "obs_pt": p.obs_pt[few],
            "obs_xy": xy[few], "obs_scale": p.obs_scale[few], "obs_slot": p.obs_slot[few]}
    alone = ba.Problem(**base)
    U = np.zeros((2, 6, 6))
    U[0] = np.linalg.cholesky(_tracking_information(T_true[0], P) * FOCAL ** 2).T
    held = ba.Problem(**{**base, "pose_sqrt_info": U})
    off = [_pose_error(ba.solve(q)[0][0], T_true[0]) for q in (alone, held)]
    assert off[1] < 0.5 * off[0]


@pytest.mark.parametrize("method", ["trf", "dogbox", "lm", "gtsam"])
def test_free_keyframes_and_depths_recover(method):
    p, T_true, rho_true, _ = _problem(np.random.default_rng(0))
    assert p.rms_px() > 1.0
    T, rho, keep = ba.solve(p, 10, 10, method=method)
    assert keep.all()
    assert _rms(p, T, rho) < 0.6  # pixels: down to the 0.5 px noise
    start = np.abs(p.T0[:2, :3, 3] - T_true[:2, :3, 3]).max()
    assert np.abs(T[:2, :3, 3] - T_true[:2, :3, 3]).max() < 0.8 * start
    assert np.median(np.abs(rho / rho_true - 1)) < np.median(np.abs(p.rho0 / rho_true - 1))
    assert np.array_equal(T[2:], p.T0[2:])  # fixed keyframes stay


def test_depth_prior_holds_an_unconstrained_point():
    p, _, _, _ = _problem(np.random.default_rng(2))
    # point 0 keeps only one observation, by a keyframe that barely moved from its host
    only = (p.obs_pt != 0) | (p.obs_kf == 1)
    p = ba.Problem(**{**p.__dict__, "obs_kf": p.obs_kf[only], "obs_pt": p.obs_pt[only],
                      "obs_xy": p.obs_xy[only], "obs_scale": p.obs_scale[only],
                      "obs_slot": p.obs_slot[only]})
    _, rho, _ = ba.solve(p)
    assert abs(rho[0] / p.rho0[0] - 1) < 0.05


def test_outlier_observations_are_dropped():
    p, _, _, bad = _problem(np.random.default_rng(1), outliers=8)
    T, rho, keep = ba.solve(p, 10, 10)
    assert not keep[bad].any()
    # the first iterations still feel the outliers, so some good observations go too
    assert keep.sum() >= 0.7 * len(keep)
    assert _rms(p, T, rho, keep) < 0.6


def test_stop_ends_the_bundle_adjustment_early():
    p, _, _, _ = _problem(np.random.default_rng(0))
    T, rho, keep = ba.solve(p, 10, 10, stop=lambda: True)
    assert np.array_equal(T, p.T0) and np.array_equal(rho, p.rho0) and keep.all()
    calls = []
    T, rho, _ = ba.solve(p, 10, 10, stop=lambda: calls.append(1) or len(calls) > 2)
    assert _rms(p, T, rho) < p.rms_px()  # what was gained so far is kept
    # checked before the first round and after each iteration; the third check stopped it,
    # and the second round did not start
    assert len(calls) == 4


CAMERA = CameraModel(320, 240, 200.0, 200.0, 160.0, 120.0)
KNOCK = {3: np.array([0.05, -0.03, 0.04, 0.004, 0.0, -0.003]),
         4: np.array([-0.04, 0.05, -0.06, 0.0, -0.004, 0.002])}


def _map(rng, seen_by: dict[int, int], n_points=80):
    """A map of five keyframes driving forward 0.5 m apart, points 6-14 m ahead hosted by the
    first two and seen by all (keyframe k by the first seen_by[k] of them); the two newest
    keyframes are knocked off their true poses. Returns (map, true T_c_w per slot, config)."""
    config = TrackerConfig(ba_min_views=2, ba_min_keyframe_obs=20)
    map_ = Map(CAMERA.width, CAMERA.height, 3, 8)
    T_true = np.array([exp_se3(np.array([0.05 * k, 0.0, -0.5 * k, 0.0, 0.01 * k, 0.0]))
                       for k in range(5)])
    host = np.arange(n_points) % 2
    px = np.column_stack([rng.uniform(40, 280, n_points), rng.uniform(40, 200, n_points)])
    f = CAMERA.unproject(px)
    P = np.zeros((n_points, 3))
    depth = rng.uniform(6, 14, n_points)
    for h in (0, 1):
        T_w_h = inv_se3(T_true[h])
        P[host == h] = (f[host == h] * depth[host == h, None]) @ T_w_h[:3, :3].T + T_w_h[:3, 3]
    pts = map_.points
    ids = np.zeros(n_points, np.int64)
    for h in (0, 1):  # the keyframes will take slots 0-4 in order
        mine = np.flatnonzero(host == h)
        rho = 1.0 / depth[mine] * (1.0 + rng.normal(0, 0.01, len(mine)))
        ids[mine] = pts.add(h, px[mine, 0], px[mine, 1], np.zeros(len(mine), np.int64),
                            f[mine], rho, 0.01 * rho, 2.0 * rho, 10.0, 10.0, inv_se3(T_true[h]))
    pts.status[ids] = CONVERGED
    for k in range(5):
        frame = Frame(k, 0.1 * k, np.zeros((CAMERA.height, CAMERA.width), np.uint8), CAMERA, 3)
        frame.T_c_w = T_true[k] if k < 3 else exp_se3(KNOCK[k]) @ T_true[k]
        seen = np.flatnonzero(host != k)[:seen_by.get(k, n_points)]
        uv = CAMERA.project(P[seen] @ T_true[k][:3, :3].T + T_true[k][:3, 3])
        uv += rng.normal(0, 0.2, uv.shape)
        frame.set_features(ids[seen], uv, np.zeros(len(seen), np.int64))
        assert map_.add_keyframe(frame) == k
    return map_, T_true, config


def _pose_error(T, T_true):
    return np.linalg.norm(inv_se3(T)[:3, 3] - inv_se3(T_true)[:3, 3])


def test_local_ba_pulls_knocked_keyframes_back_and_the_last_frame_follows():
    map_, T_true, config = _map(np.random.default_rng(3), {2: 60, 3: 60})
    before = [_pose_error(map_.kf_T_c_w[s], T_true[s]) for s in (3, 4)]
    last_T = exp_se3(np.array([0.0, 0.0, -0.3, 0.0, 0.0, 0.0])) @ map_.kf_T_c_w[4]
    relative = last_T @ inv_se3(map_.kf_T_c_w[4])
    followed = []

    def follow(moved):
        assert {3, 4} <= set(moved)
        followed.append(ba.follow(last_T, map_.keyframes[4].feat_point, map_, moved))

    assert ba.local_ba(map_, 4, CAMERA, config, moved_keyframes=follow) > 0
    after = [_pose_error(map_.kf_T_c_w[s], T_true[s]) for s in (3, 4)]
    assert max(after) < 0.3 * min(before)
    assert np.array_equal(map_.kf_T_c_w[0], T_true[0])  # the gauge stays
    # the last frame keeps its pose relative to the keyframe it shares its points with
    np.testing.assert_allclose(followed[0] @ inv_se3(map_.kf_T_c_w[4]), relative, atol=1e-9)


def test_points_a_moved_keyframe_hosts_move_with_it():
    """A candidate hosted by a keyframe the BA moves is not in the problem (not converged);
    it keeps its place relative to its host (the depth filter's estimate is the host's),
    so tracking after the BA sees one consistent map."""
    map_, _, config = _map(np.random.default_rng(3), {2: 60, 3: 60})
    pts = map_.points
    f = CAMERA.unproject(np.array([[100.0, 80.0], [200.0, 150.0]]))
    rho = np.array([0.1, 0.2])
    cand = pts.add(4, np.array([100.0, 200.0]), np.array([80.0, 150.0]), np.zeros(2, np.int64),
                   f, rho, 0.1 * rho, 2.0 * rho, 10.0, 10.0, inv_se3(map_.kf_T_c_w[4]))
    before = pts.pos_w[cand].copy()
    assert ba.local_ba(map_, 4, CAMERA, config) > 0
    T = map_.kf_T_c_w[4]
    assert np.linalg.norm(pts.pos_w[cand] - before, axis=1).min() > 1e-3  # it moved
    np.testing.assert_allclose(pts.pos_w[cand] @ T[:3, :3].T + T[:3, 3], f / rho[:, None],
                               atol=1e-9)


def _overconfident_depths(inflation: float) -> tuple[float, float]:
    """A BA on a map at its true poses (keyframes 2-4 tracked: their tracking information is
    their prior) whose depth filters all put their points 3 % too near, claiming 1 %: the
    free keyframes' largest position error (m) and the points' median depth error after."""
    map_, T_true, config = _map(np.random.default_rng(7), {})
    pts = map_.points
    alive = pts.alive()
    rho_true = pts.rho[alive].copy()  # within 1 % of the truth
    for k in (2, 3, 4):
        map_.kf_T_c_w[k] = map_.keyframes[k].T_c_w = T_true[k]
        seen = map_.keyframes[k].feat_point
        map_.keyframes[k].pose_info = _tracking_information(T_true[k], pts.pos_w[seen])
    pts.rho[alive] *= 1.03
    for h in (0, 1):
        pts.update_positions(alive[pts.host[alive] == h], inv_se3(T_true[h]))
    config.ba_min_rms_px = 0.0
    config.ba_depth_prior_inflation = inflation
    assert ba.local_ba(map_, 4, CAMERA, config) > 0
    pose = max(_pose_error(map_.kf_T_c_w[s], T_true[s]) for s in (2, 3, 4))
    return pose, float(np.median(np.abs(pts.rho[alive] / rho_true - 1)))


def test_inflated_depth_priors_let_the_views_correct_the_points_not_the_keyframes():
    """Held to an overconfident depth filter, the BA moves the keyframes to fit its wrong
    depths; a looser prior lets the views correct the depths and keeps the keyframes."""
    pose1, depth1 = _overconfident_depths(1.0)
    pose3, depth3 = _overconfident_depths(3.0)
    assert pose3 < 0.6 * pose1
    assert depth3 < 0.8 * depth1


def test_a_keyframe_the_window_barely_sees_is_held():
    map_, _, config = _map(np.random.default_rng(4), {4: 12})
    p = ba.build_problem(map_, 3, CAMERA, config)
    free = set(p.slots[:p.n_free].tolist())
    assert 3 in free and 4 not in free and 4 in set(p.slots.tolist())


def test_the_trackers_last_frame_follows_a_bundle_adjustment():
    """Threaded mapping: the BA ran on a keyframe while the tracker went on; its last frame
    (the next frame's prior) moves along under the map lock; a keyframe as last frame is the
    map's and was moved by the BA itself."""
    tracker = Tracker(CAMERA, TrackerConfig(local_ba=True))
    tracker.map, _, config = _map(np.random.default_rng(5), {2: 60, 3: 60})
    tracker.mapper.map = tracker.map
    last = Frame(9, 0.9, np.zeros((CAMERA.height, CAMERA.width), np.uint8), CAMERA, 3)
    last.T_c_w = exp_se3(np.array([0.0, 0.0, -0.3, 0.0, 0.0, 0.0])) @ tracker.map.kf_T_c_w[4]
    last.set_features(tracker.map.keyframes[4].feat_point, np.zeros((80, 2)),
                      np.zeros(80, np.int64))
    tracker.tracking.last = last
    relative = last.T_c_w @ inv_se3(tracker.map.kf_T_c_w[4])
    assert ba.local_ba(tracker.map, 4, CAMERA, config,
                       moved_keyframes=tracker.mapper.after_ba) > 0
    np.testing.assert_allclose(last.T_c_w @ inv_se3(tracker.map.kf_T_c_w[4]), relative,
                               atol=1e-9)
    keyframe = tracker.tracking.last = tracker.map.keyframes[4]
    before = keyframe.T_c_w.copy()
    tracker._follow_ba({4: (np.eye(4), exp_se3(np.full(6, 0.01)))})
    assert np.array_equal(keyframe.T_c_w, before)


def test_free_keyframes_bring_their_tracking_information():
    """A tracked keyframe's pose information becomes its prior (in pixels); the initial map's
    keyframes (not tracked) get none; the prior can be switched off."""
    map_, T_true, config = _map(np.random.default_rng(4), {})
    P = map_.points.pos_w[map_.keyframes[3].feat_point]
    map_.keyframes[3].pose_info = _tracking_information(T_true[3], P)
    p = ba.build_problem(map_, 3, CAMERA, config)
    free = p.slots[:p.n_free].tolist()
    assert 3 in free and 4 in free
    U = p.pose_sqrt_info
    info = map_.keyframes[3].pose_info * CAMERA.fx * CAMERA.fy
    np.testing.assert_allclose(U[free.index(3)].T @ U[free.index(3)], info,
                               atol=1e-9 * np.abs(info).max())
    assert not U[free.index(4)].any()
    config.ba_keyframe_prior = False
    assert ba.build_problem(map_, 3, CAMERA, config).pose_sqrt_info is None


def _with_pose_priors(p, rng):
    """p with a random positive definite square-root information on each free keyframe."""
    M = rng.normal(0, 1, (p.n_free, 6, 6))
    U = np.array([np.linalg.cholesky(m @ m.T + np.eye(6)).T * 50.0 for m in M])
    return ba.Problem(**{**p.__dict__, "pose_sqrt_info": U})


def test_gtsam_graph_has_the_scipy_cost():
    """Same residuals: the GTSAM factor graph's error at moved keyframes and depths is the
    scipy path's cost, pose priors included."""
    gtsam = pytest.importorskip("gtsam")
    from vo import ba_gtsam

    rng = np.random.default_rng(0)
    p = _with_pose_priors(_problem(rng)[0], rng)
    keep = rng.random(len(p.obs_kf)) > 0.1
    T = p.T0.copy()
    for k in range(p.n_free):
        T[k] = exp_se3(rng.normal(0, 0.02, 6)) @ T[k]
    rho = p.rho0 * (1.0 + rng.normal(0, 0.01, len(p.rho0)))
    values = gtsam.Values()
    for k in range(p.n_free):
        values.insert(ba_gtsam._pose_key(gtsam, k), gtsam.Pose3(T[k]))
    for j, r in enumerate(rho):
        values.insert(ba_gtsam._rho_key(gtsam, j), np.array([r]))
    graph = ba_gtsam._graph(gtsam, p, keep)
    assert graph.error(values) == pytest.approx(ba.cost(p, T, rho, keep), rel=1e-9)
    assert ba.cost(p, T, rho, keep) > 2 * ba.cost(p, p.T0, p.rho0, keep)  # T, rho matter


def test_gtsam_point_jacobians_match_central_differences():
    """By the inverse depth and by GTSAM's right perturbation (w, v) of host and observer."""
    gtsam = pytest.importorskip("gtsam")
    from vo.ba_gtsam import point_residuals

    rng = np.random.default_rng(1)
    T_h = exp_se3(rng.normal(0, 0.3, 6))
    T_k = np.array([exp_se3(rng.normal(0, 0.3, 6)) for _ in range(3)])
    f = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    xy, scale = rng.normal(0, 0.1, (3, 2)), np.array([400.0, 200.0, 100.0])
    _, (d_rho, d_obs, d_host) = point_residuals(T_h, T_k, f, 0.25, xy, scale)

    def moved(T, xi):
        return gtsam.Pose3(T).retract(xi).matrix()

    def observer(xi):
        T = T_k.copy()
        T[1] = moved(T_k[1], xi)
        return point_residuals(T_h, T, f, 0.25, xy, scale)[0]

    by_rho = _central_differences(
        lambda r: point_residuals(T_h, T_k, f, r[0], xy, scale)[0], np.array([0.25]))
    by_host = _central_differences(
        lambda xi: point_residuals(moved(T_h, xi), T_k, f, 0.25, xy, scale)[0], np.zeros(6))
    by_observer = _central_differences(observer, np.zeros(6))
    np.testing.assert_allclose(d_rho, by_rho[:, 0], atol=1e-6 * np.abs(by_rho).max())
    np.testing.assert_allclose(d_host, by_host, atol=1e-6 * np.abs(by_host).max())
    np.testing.assert_allclose(d_obs[2:4], by_observer[2:4], atol=1e-6 * np.abs(d_obs).max())
    assert not by_observer[[0, 1, 4, 5]].any()  # observer 1 moves only its own rows


def test_gtsam_and_scipy_reach_the_same_answer_with_outliers_and_pose_priors():
    pytest.importorskip("gtsam")
    rng = np.random.default_rng(3)
    p, _, _, bad = _problem(rng, outliers=6)
    p = _with_pose_priors(p, rng)
    T1, rho1, keep1 = ba.solve(p, 10, 10, method="trf")
    T2, rho2, keep2 = ba.solve(p, 10, 10, method="gtsam")
    assert not keep1[bad].any() and not keep2[bad].any()
    assert np.array_equal(keep1, keep2)
    assert ba.cost(p, T2, rho2, keep2) == pytest.approx(ba.cost(p, T1, rho1, keep1), rel=1e-3)
    np.testing.assert_allclose(T2[:2], T1[:2], atol=1e-4)
    np.testing.assert_allclose(rho2, rho1, rtol=1e-3)
    assert np.array_equal(T2[2:], p.T0[2:])  # fixed keyframes stay


def test_gtsam_stops_early_and_a_missing_gtsam_is_a_clear_error(monkeypatch):
    pytest.importorskip("gtsam")
    import importlib.util

    from sdvl.errors import InputError

    p, _, _, _ = _problem(np.random.default_rng(0))
    T, rho, keep = ba.solve(p, 10, 10, method="gtsam", stop=lambda: True)
    assert np.array_equal(T, p.T0) and np.array_equal(rho, p.rho0) and keep.all()
    calls = []
    T, rho, _ = ba.solve(p, 10, 10, method="gtsam", stop=lambda: calls.append(1) or len(calls) > 2)
    assert _rms(p, T, rho) < p.rms_px()
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(InputError, match="pip install 'sdvl-companion\\[gtsam\\]'"):
        TrackerConfig(ba_method="gtsam")


def test_problem_observers_see_each_problem_as_built():
    """What `sdvl ba-bench` captures: the problem before it is solved, with its map."""
    map_, _, config = _map(np.random.default_rng(3), {2: 60, 3: 60})
    start = map_.kf_T_c_w.copy()
    seen = []
    ba.PROBLEM_OBSERVERS.append(lambda p, m: seen.append((p, m)))
    try:
        assert ba.local_ba(map_, 4, CAMERA, config) > 0
    finally:
        ba.PROBLEM_OBSERVERS.pop()
    [(problem, observed_map)] = seen
    assert observed_map is map_
    assert 4 in problem.slots[:problem.n_free].tolist()
    np.testing.assert_array_equal(problem.T0, start[problem.slots])
    assert not np.array_equal(map_.kf_T_c_w[4], start[4])  # solved after it was seen
