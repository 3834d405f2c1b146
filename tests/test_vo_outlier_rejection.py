"""Outlier rejection (thesis 6.8): the numba RANSAC against a slow reference, and a flight over a
plane with a large object moving through the view."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_vo_tracker import _flight
from vo_scenes import load_texture, render_plane, small_camera

from sim.metrics import evaluate
from sim.trajectory import Trajectory
from vo import outlier_rejection as orj
from vo.config import TrackerConfig
from vo.se3 import exp_se3
from vo.tracker import Tracker


def _reference_ransac(pos_w, obs, scale, T_prior, subsets, threshold, p, T_first):
    """Eq. 6.12 RANSAC written plainly: numerical Jacobians, Python loops; T_first the first
    hypothesis, the others fitted with the level weights; inliers by the unweighted error."""
    def errors(T, idx, weight=scale):
        X = pos_w[idx] @ T[:3, :3].T + T[:3, 3]
        return ((obs[idx] - X[:, :2] / X[:, 2:]) * weight[idx, None]).ravel()

    def needed_for(count):
        w = (count / len(pos_w)) ** orj.SUBSET
        return 1 if w >= 1 else min(len(subsets), int(np.ceil(np.log(1 - p) / np.log(1 - w))))

    err = errors(T_first, np.arange(len(pos_w)), np.ones(len(pos_w))).reshape(-1, 2)
    best = (err ** 2).sum(axis=1) < threshold ** 2
    best_count, tried = best.sum(), 0
    needed = needed_for(best_count) if best_count else len(subsets)
    while tried < needed:
        T = T_prior.copy()
        for _ in range(orj.HYPOTHESIS_ITERATIONS):
            e = errors(T, subsets[tried])
            J = np.column_stack([(errors(exp_se3(1e-7 * np.eye(6)[a]) @ T, subsets[tried]) - e)
                                 / 1e-7 for a in range(6)])
            T = exp_se3(np.linalg.lstsq(J, -e, rcond=None)[0]) @ T
        tried += 1
        err = errors(T, np.arange(len(pos_w)), np.ones(len(pos_w))).reshape(-1, 2)
        inlier = (err ** 2).sum(axis=1) < threshold ** 2
        if inlier.sum() > best_count:
            best, best_count = inlier, inlier.sum()
            needed = needed_for(best_count)
    return best, tried


def _plain(n: int) -> np.ndarray:
    """No whitening: identity matrices for n matches."""
    return np.broadcast_to(np.eye(2), (n, 2, 2)).copy()


def test_the_first_rows_of_subsets_do_not_depend_on_how_many_are_drawn():
    """RANSAC draws as many as it needs: the rows it tries are those of the whole cap."""
    whole = orj.random_subsets(40, 30, 7)
    assert np.array_equal(orj.random_subsets(40, 4, 7), whole[:4])


def test_a_hypothesis_is_scored_only_while_it_can_beat_the_best():
    """count_within counts the matches within the threshold, or says -1 as soon as the rest
    could not bring it to `enough`."""
    rng = np.random.default_rng(4)
    pos_w = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50),
                             rng.uniform(2, 4, 50)])
    obs = pos_w[:, :2] / pos_w[:, 2:] + rng.normal(0, 0.004, (50, 2))
    thr2 = 0.004 ** 2
    plain = _plain(50)
    within = int((orj.squared_errors(pos_w, obs, plain, np.eye(4)) < thr2).sum())
    assert 0 < within < 50
    assert orj.count_within(pos_w, obs, plain, np.eye(4), thr2, within) == within
    assert orj.count_within(pos_w, obs, plain, np.eye(4), thr2, within + 1) == -1


def test_ransac_matches_the_reference_and_finds_the_outliers():
    rng = np.random.default_rng(1)
    n = 80
    pos_w = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(2, 4, n)])
    T_true = exp_se3(np.array([0.05, -0.02, 0.03, 0.01, -0.02, 0.015]))
    X = pos_w @ T_true[:3, :3].T + T_true[:3, 3]
    obs = X[:, :2] / X[:, 2:] + rng.normal(0, 0.3 / 500, (n, 2))
    outliers = rng.choice(n, 30, replace=False)
    obs[outliers] += rng.uniform(0.02, 0.05, (30, 2)) * rng.choice([-1, 1], (30, 2))
    scale = 1.0 / 2.0 ** rng.integers(0, 3, n)
    subsets = orj.random_subsets(n, 100, 7)
    truth = np.ones(n, bool)
    truth[outliers] = False
    # random subsets; then subsets of outliers only (as when blur leaves no 5 matches that
    # agree), without and with a good first hypothesis (the robust fit to all matches)
    hopeless = outliers[orj.random_subsets(30, 100, 3)]
    cases = [(np.eye(4), subsets, True), (np.eye(4), hopeless, False), (T_true, hopeless, True)]
    for T_first, rows, finds_them in cases:
        args = (pos_w, obs, scale, np.eye(4), rows, 2.0 / 500, 0.99, T_first)
        inlier, tried = orj.ransac(*args[:2], _plain(n), *args[2:4], lambda k, r=rows: r[:k],
                                   *args[5:7], len(rows), T_first)
        ref_inlier, ref_tried = _reference_ransac(*args)
        assert np.array_equal(inlier, ref_inlier) and tried == ref_tried
        assert np.array_equal(inlier, truth) == finds_them
        if finds_them:
            assert tried < 100  # 37% outliers: eq. 6.12 asks for about 45 hypotheses


def test_an_error_along_an_uncertain_depth_is_judged_whitened():
    """A match off along the direction its point's depth is uncertain in passes the
    threshold when whitened for it (as the pose refinement weights it), one off across that
    direction does not; unwhitened both fail."""
    pos_w = np.array([[0.0, 0.0, 2.0], [0.2, 0.1, 2.0]])
    obs = pos_w[:, :2] / pos_w[:, 2:] + np.array([[0.02, 0.0], [0.0, 0.02]])
    beta = 1.0 - 1.0 / np.sqrt(1.0 + 10.0 ** 2)  # a depth interval spanning 10 pixel sigmas
    along_x = np.eye(2) - beta * np.outer([1.0, 0.0], [1.0, 0.0])  # depth_whitening's form
    whiten = np.stack([along_x, along_x])
    thr2 = 0.01 ** 2
    assert np.array_equal(orj.squared_errors(pos_w, obs, whiten, np.eye(4)) < thr2,
                          [True, False])
    assert not np.any(orj.squared_errors(pos_w, obs, _plain(2), np.eye(4)) < thr2)
    assert orj.count_within(pos_w, obs, whiten, np.eye(4), thr2, 0) == 1


def _mover(frame: np.ndarray, i: int, tex: np.ndarray) -> np.ndarray:
    """A textured board a third of the image wide sliding across the view."""
    out = frame.copy()
    h, w = frame.shape
    bw, bh = w // 3, h // 2
    x0 = int((i * 3) % (w + bw)) - bw
    board = tex[100:100 + bh, 300:300 + bw]
    lo, hi = max(x0, 0), min(x0 + bw, w)
    if hi > lo:
        out[h // 4:h // 4 + bh, lo:hi] = board[:, lo - x0:hi - x0]
    return out


@pytest.fixture(scope="module")
def flights(data_dir):
    cam = small_camera()
    tex = load_texture(data_dir)
    poses = [_flight(i) for i in range(150)]
    calm = [(i / 30.0, render_plane(tex, cam, T)) for i, T in enumerate(poses)]
    busy = [(t, _mover(img, i, tex) if i >= 30 else img) for i, (t, img) in enumerate(calm)]
    gt = Trajectory.from_matrices(np.array([f[0] for f in calm]),
                                  np.array([np.linalg.inv(T) for T in poses]))
    return cam, calm, busy, gt


def _inliers_on_mover(tracker: Tracker, stamp: float, image: np.ndarray,
                      still: np.ndarray) -> int:
    """How many pose inliers of the frame just tracked (at stamp) lie where image differs from
    `still`, the same view without the moving objects (the difference grown by 2 px)."""
    last = tracker.last
    if last is None or last.t != stamp or not len(last.feat_px):
        return 0
    mover = cv2.dilate((cv2.absdiff(image, still) > 8).astype(np.uint8), np.ones((5, 5), np.uint8))
    h, w = image.shape
    u = np.clip(np.round(last.feat_px[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.round(last.feat_px[:, 1]).astype(int), 0, h - 1)
    return int(mover[v, u].sum())


def _ate(cam, frames, gt, rejection: bool, still=None) -> tuple[float, int, int]:
    """ATE (Sim(3)), frames tracked and, given the frames without the mover (`still`), the pose
    inliers on the mover over the flight."""
    tracker = Tracker(cam, TrackerConfig(outlier_rejection=rejection))
    t, T, on_mover = [], [], 0
    for k, (stamp, image) in enumerate(frames):
        r = tracker.process(image, stamp)
        if r.has_pose:
            t.append(stamp)
            T.append(r.T_w_c)
            if still is not None:
                on_mover += _inliers_on_mover(tracker, stamp, image, still[k][1])
    est = Trajectory.from_matrices(np.array(t), np.array(T))
    return evaluate(gt, est, "sim3").ate_rmse_m, len(t), on_mover


def _poses(cam, frames, seed: int) -> np.ndarray:
    """Every pose the tracker reports over the frames, with outlier rejection seeded by seed."""
    tracker = Tracker(cam, TrackerConfig(outlier_rejection=True, seed=seed))
    results = (tracker.process(image, stamp) for stamp, image in frames)
    return np.array([r.T_w_c for r in results if r.has_pose])


def test_a_seeded_run_repeats_bit_for_bit(flights):
    cam, _, busy, _ = flights
    frames = busy[:70]
    first = _poses(cam, frames, 0)
    assert len(first) > 30
    assert np.array_equal(first, _poses(cam, frames, 0))


def test_rejection_keeps_a_moving_object_out_of_the_pose(flights):
    cam, calm, busy, gt = flights
    calm_ate, _, _ = _ate(cam, calm, gt, True)
    with_rejection, n_with, on_with = _ate(cam, busy, gt, True, calm)
    without, _, on_without = _ate(cam, busy, gt, False, calm)
    assert n_with >= 0.9 * len(busy)
    # the object stays out of the pose: near the calm flight's error, below the error without
    # rejection, and under 60% of the matches on the board the pose takes without rejection
    # (0.39-0.43 over RANSAC seeds 0-4; 1.15 with 50 px thresholds). Not the ATE against the
    # run without rejection below a ratio: the keyframe policy moves that one (0.84-0.95 x
    # with grid-cell keyframes, 0.56 x with inlier counts; RESULTS.md: tracker-kf-cells-movers)
    assert with_rejection <= 1.5 * calm_ate
    assert with_rejection < without
    assert on_with < 0.6 * on_without


WALKERS_SIZE = (320, 240)


def _track_walkers() -> dict[str, tuple[float, int, int, int]]:
    """Three runs (the key): the walkers flight at WALKERS_SIZE "with" and "without" rejection,
    and its "empty" twin (no people) with it; each: ATE (Sim(3)), frames tracked, frames, and
    the pose inliers on people once the group has walked off. The trackers take turns on each
    rendered frame, so both flights are rendered once."""
    from sim.synth.flight import synthetic_sequence
    from sim.synth.presets import walkers

    crowd = [w for w in walkers(0, "procedural").scene.movers if w.pause > 0]
    walked_off = max(w.t_start + w.pause_after + w.pause for w in crowd)
    seq, empty = (synthetic_sequence(p, size=WALKERS_SIZE, textures="procedural")
                  for p in ("walkers", "walkers-empty"))
    runs = {name: (Tracker(seq.camera, TrackerConfig(outlier_rejection=on)), [], [], [0])
            for name, on in (("with", True), ("without", False), ("empty", True))}
    for (stamp, image), (_, still) in zip(seq.frames(None), empty.frames(None), strict=True):
        for name, (tracker, t, T, on_people) in runs.items():
            seen = still if name == "empty" else image
            r = tracker.process(seen, stamp)
            if r.has_pose:
                t.append(stamp)
                T.append(r.T_w_c)
                if stamp >= walked_off:
                    on_people[0] += _inliers_on_mover(tracker, stamp, seen, still)
    out = {}
    for name, (_, t, T, on_people) in runs.items():
        est = Trajectory.from_matrices(np.array(t), np.array(T))
        out[name] = (evaluate(seq.groundtruth, est, "sim3").ate_rmse_m, len(t), len(seq),
                     on_people[0])
    return out


def test_rejection_keeps_people_who_walk_off_out_of_the_pose():
    runs = _track_walkers()
    with_rejection, tracked, frames, on_with = runs["with"]
    on_without = runs["without"][3]
    assert tracked >= 0.9 * frames
    # the people who walk off stay out of the pose: it takes under 60% of the matches on them
    # it takes without rejection (0.39-0.45 over RANSAC seeds 0-4, 0.79 with 50 px thresholds).
    # The ATE follows the RANSAC seed (0.030-0.053 m, 0.038 without rejection) and the keyframe
    # policy, its excess over the empty square made while the people still stand (RESULTS.md:
    # tracker-kf-cells-movers): within 5x the empty square's (3.3-4.6x over RANSAC seeds 0-4;
    # 3.3-4.9x before keyframes needed a new view: RESULTS.md, tracker-kf-baseline)
    assert on_with < 0.6 * on_without
    assert with_rejection <= 5.0 * runs["empty"][0]


def _three_matches():
    """A MapMatcher factory (by TrackerConfig options) over a map of three points: a candidate
    its depth filter holds likely an inlier (0.8), an unlikely candidate (0.2), a converged
    point (0.8); their ids and one whitening for all three."""
    from calib.camera import CameraModel
    from vo.map import CONVERGED, Map
    from vo.map_matching import MapMatcher
    from vo.reprojector import Reprojector

    camera = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    map_ = Map(64, 48, 3, 4)
    ids = map_.points.add(0, np.zeros(3), np.zeros(3), np.zeros(3, np.int64),
                          np.tile([0.0, 0.0, 1.0], (3, 1)), np.ones(3), np.full(3, 0.5),
                          np.ones(3), 10.0, 10.0, np.eye(4))
    map_.points.a[ids], map_.points.b[ids] = [8.0, 2.0, 8.0], [2.0, 8.0, 2.0]
    map_.points.status[ids[2]] = CONVERGED

    def matcher(**options):
        config = TrackerConfig(**options)
        return MapMatcher(camera, config, map_, Reprojector(camera, config))

    return matcher, ids, np.tile(np.diag([0.1, 1.0]), (3, 1, 1))


def test_the_gate_whitens_only_candidates_likely_inliers():
    """ransac_whitening_min_inlier: of three matches with the same whitening, the candidate the
    depth filter holds likely an inlier is judged whitened; the unlikely candidate and the
    converged point are judged plainly; without the option all are whitened, and without
    ransac_depth_whitening none."""
    matcher, ids, whiten = _three_matches()

    def judged(**options):
        return matcher(**options)._judged(ids, whiten)

    gated = judged(ransac_depth_whitening=True, ransac_whitening_min_inlier=0.5)
    assert np.array_equal(gated[0], whiten[0])
    assert np.array_equal(gated[1:], np.tile(np.eye(2), (2, 1, 1)))
    assert np.array_equal(judged(ransac_depth_whitening=True), whiten)
    assert np.array_equal(judged(), np.tile(np.eye(2), (3, 1, 1)))


def test_the_rescue_whitens_candidates_and_leaves_converged_points_as_ransac_judged():
    """rescue_depth_whitening: the rescue judges both candidates whitened (with
    rescue_whitening_min_inlier 0.5 only the likely one) and the converged point as RANSAC
    did; without it, as RANSAC did."""
    matcher, ids, whiten = _three_matches()
    plain = np.tile(np.eye(2), (3, 1, 1))

    def rescue(**options):
        return matcher(**options)._rescue_judged(ids, whiten, plain)

    assert np.array_equal(rescue(), plain)
    every = rescue(rescue_depth_whitening=True)
    assert np.array_equal(every[:2], whiten[:2]) and np.array_equal(every[2], np.eye(2))
    gated = rescue(rescue_depth_whitening=True, rescue_whitening_min_inlier=0.5)
    assert np.array_equal(gated[0], whiten[0]) and np.array_equal(gated[1:], plain[1:])


def _interval_scene(conv_depth: float, cand_sigma: float, tried: int = 100, **options):
    """A frame 0.10 m sideways of its host keyframe matching 12 converged points 2 m away
    (stored at conv_depth: at 3 m they agree on a wrong 0.15 m move) and 30 candidates stored
    at 0.5 m with inverse depth sigma cand_sigma, truly 8-18 px off along their epipolar lines
    (inverse depths 1.6-1.84 and 2.16-2.36), of `tried` points tried: a MapMatcher with outlier
    rejection and `options`, the frame (at the true pose) and its matches."""
    from calib.camera import CameraModel
    from vo.frame import Frame
    from vo.map import CONVERGED, Map
    from vo.map_matching import MapMatcher, Matches
    from vo.reprojector import Reprojector

    rng = np.random.default_rng(3)
    camera = CameraModel(640, 480, 500.0, 500.0, 319.5, 239.5)
    map_ = Map(640, 480, 42, 4)
    n_conv, n_cand = 12, 30
    px = rng.uniform([60, 60], [580, 420], (n_conv + n_cand, 2))
    f = camera.unproject(px)
    rho_true = np.concatenate((np.full(n_conv, 0.5), rng.uniform(1.6, 1.84, n_cand // 2),
                               rng.uniform(2.16, 2.36, n_cand // 2)))
    rho = np.concatenate((np.full(n_conv, 1.0 / conv_depth), np.full(n_cand, 2.0)))
    sigma = np.concatenate((np.full(n_conv, 1e-3), np.full(n_cand, cand_sigma)))
    ids = map_.points.add(0, px[:, 0], px[:, 1], np.zeros(len(px), np.int64), f, rho, sigma,
                          np.ones(len(px)), 10.0, 10.0, np.eye(4))
    map_.points.status[ids[:n_conv]] = CONVERGED
    T_c_w = np.eye(4)
    T_c_w[0, 3] = -0.1
    truth = f / rho_true[:, None]  # a point is its bearing over its inverse depth
    uv = camera.project(truth @ T_c_w[:3, :3].T + T_c_w[:3, 3])
    config = TrackerConfig(outlier_rejection=True, **options)
    matcher = MapMatcher(camera, config, map_, Reprojector(camera, config))
    frame = Frame(1, 0.0, np.zeros((480, 640), np.uint8), camera, 1)
    frame.T_c_w = T_c_w.copy()
    m = Matches(ids, uv, np.zeros(len(ids), np.int64), tried, tried, ids,
                np.zeros(len(ids), bool), T_c_w, None, 0.0)
    return matcher, frame, m


def _judged_at(move: float, conv_depth: float, cand_sigma: float, across_px: float = 0.0,
               level: int = 0, inliers: int = 12):
    """_interval_scene's frame judged at a pose `move` m sideways with the first `inliers`
    converged points as its inliers, every match shifted across its epipolar line by
    across_px level-0 pixels and found at `level`: (matches along their intervals, quality,
    held)."""
    matcher, _, m = _interval_scene(conv_depth, cand_sigma)
    m.T = np.eye(4)
    m.T[0, 3] = -move
    m.inlier[:inliers] = True
    m.uv = m.uv + np.array([0.0, across_px])
    m.levels[:] = level
    m.n_along = matcher._along(m.ids, matcher.normalised(m.uv), m.levels, m.T)
    return m.n_along, matcher.quality(m), matcher.held(m)


def test_a_bad_frame_is_held_when_its_matches_agree_along_their_depth_intervals():
    """12 inliers of 100 tried: a bad frame, whatever the candidates say. At the true pose
    the candidates lie on the segments their 2-sigma intervals (2 +- 0.4) project to: held
    (tracked on from, not published). At a consensus on a wrong move (0.15 m for 0.10) they
    do not: not held. Candidates whose interval reaches out to infinity (2 +- 3) agree with
    either move along their lines: held, never published. 3 px across the lines is off at
    level 0 and on at level 1 (2 px at the match's level). A pose from 5 inliers is not
    held, whatever agrees with it."""
    from vo.result import Quality

    assert _judged_at(0.10, 2.0, 0.2) == (42, Quality.BAD, True)
    assert _judged_at(0.15, 3.0, 0.2) == (12, Quality.BAD, False)
    assert _judged_at(0.15, 3.0, 1.5) == (42, Quality.BAD, True)
    assert _judged_at(0.10, 2.0, 0.2, across_px=3.0) == (0, Quality.BAD, False)
    assert _judged_at(0.10, 2.0, 0.2, across_px=3.0, level=1) == (42, Quality.BAD, True)
    assert _judged_at(0.10, 2.0, 0.2, inliers=5) == (42, Quality.BAD, False)


def test_holding_leaves_the_pose_and_its_matches_to_ransac():
    """With candidates out to infinity (2 +- 3) RANSAC keeps them out of the pose: 12
    inliers of 200 tried, a bad frame. hold_frames changes neither the pose, its inliers nor
    its quality; it counts all 42 matches along their lines and holds the frame, also when
    the converged points agree on the wrong 0.15 m move (which is never published)."""
    from vo.result import Quality

    def refined(conv_depth: float, **options):
        matcher, frame, m = _interval_scene(conv_depth, 1.5, 200, **options)
        matcher._refine(frame, m, {})
        return m, matcher.quality(m), matcher.held(m)

    for conv_depth, move in ((2.0, 0.10), (3.0, 0.15)):
        plain, plain_q, plain_held = refined(conv_depth, hold_frames=False)
        m, quality, held = refined(conv_depth)
        assert np.array_equal(plain.inlier, m.inlier) and np.array_equal(plain.T, m.T)
        assert abs(m.T[0, 3] + move) < 0.005 and m.n_inliers == 12
        assert plain_q == quality == Quality.BAD and not plain_held and plain.n_along == 0
        assert held and m.n_along == 42
