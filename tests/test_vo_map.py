"""Map storage: slot recycling is delayed, removing a keyframe drops what it hosts, the store
stays bounded under churn, a keyframe observes only live points; the points seen for the
keyframe policy count grid cells; tracking matches one point per cell, more while they are
crowded; quality classification of 6.10."""

from __future__ import annotations

import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.map import CANDIDATE, CONVERGED, DELETED, FREE, RELEASE_DELAY, Map
from vo.quality import LostCounter, classify
from vo.reprojector import Reprojector


def _add(store, n, host=0):
    f = np.tile([0.0, 0.0, 1.0], (n, 1))
    return store.add(host, np.zeros(n), np.zeros(n), np.zeros(n, np.int64), f, np.ones(n),
                     np.ones(n), np.ones(n), 10.0, 10.0, np.eye(4))


def test_recycling_waits_and_store_stays_bounded():
    m = Map(64, 48, 3, 5)
    pts = m.points
    first = _add(pts, 100)
    assert (pts.status[first] == CANDIDATE).all()
    pts.delete(first[:50])
    assert (pts.status[first[:50]] == DELETED).all()
    again = _add(pts, 50)
    assert not np.intersect1d(again, first[:50]).size  # not reused yet
    for frame in range(RELEASE_DELAY):
        pts.step(frame)
    assert (pts.status[first[:50]] == FREE).all()
    capacity = pts.capacity
    for frame in range(200):  # steady churn reuses slots
        pts.newest_frame = frame
        ids = _add(pts, 40)
        pts.delete(ids)
        pts.step(frame)
    assert pts.capacity == capacity


def test_recycling_waits_for_the_frames_tracked_before_the_deletion():
    """A mapper behind tracking (threaded) still has frames to map that may have matched a
    deleted point: its slot is freed only once a frame tracked after the deletion is mapped,
    however many mapping steps pass before."""
    pts = Map(64, 48, 3, 5).points
    ids = _add(pts, 10)
    pts.newest_frame = 7  # tracking is at frame 7; the mapper is at frame 3
    pts.delete(ids)
    for frame in range(3, 8):
        pts.step(frame)
        assert (pts.status[ids] == DELETED).all(), frame
    pts.step(8)
    assert (pts.status[ids] == FREE).all()


def test_removing_a_keyframe_drops_its_points_and_observations():
    cam = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    m = Map(64, 48, 3, 5)
    img = np.zeros((48, 64), np.uint8)
    kf0 = Frame(0, 0.0, img, cam, 3)
    slot0 = m.add_keyframe(kf0)
    ids = _add(m.points, 20, host=slot0)
    kf1 = Frame(1, 1.0, img, cam, 3)
    kf1.set_features(ids[:15], np.zeros((15, 2)), np.zeros(15, np.int64))
    slot1 = m.add_keyframe(kf1)
    assert m.covisible(ids, exclude=slot0, min_shared=10) == [slot1]
    m.remove_keyframe(slot0)
    assert (m.points.status[ids] == DELETED).all()
    m.prune_observations()
    assert len(m.obs) == 0 and len(m) == 1


def test_a_keyframe_observes_only_live_points_after_its_slots_are_recycled():
    # relocalisation aligns to old keyframes through what they observe: their feature lists
    # name slots that points created since may have taken over
    cam = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    m = Map(64, 48, 3, 5)
    ids = _add(m.points, 20, host=1)  # hosted by another keyframe: observations only
    kf = Frame(0, 0.0, np.zeros((48, 64), np.uint8), cam, 3)
    uv = np.arange(40.0).reshape(20, 2)
    kf.set_features(ids, uv, np.zeros(20, np.int64))
    slot = m.add_keyframe(kf)
    m.points.delete(ids[:8])
    for _ in range(RELEASE_DELAY):
        m.points.step(0)
    m.prune_observations()
    reused = _add(m.points, 8, host=1)
    assert np.intersect1d(reused, kf.feat_point).size == 8
    seen, px = m.observed_by(slot)
    assert np.array_equal(seen, ids[8:]) and np.array_equal(px, uv[8:])


def test_a_keyframe_observes_the_candidates_it_hosts_once():
    """Relocalisation aligns to a keyframe through the points it hosts too, candidates (a map
    of rotations converges few points) and converged ones, at the pixels where the keyframe
    detected them; a point it also observes is listed once, deleted ones not at all."""
    cam = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    m = Map(64, 48, 3, 5)
    kf = Frame(0, 0.0, np.zeros((48, 64), np.uint8), cam, 3)
    kf.set_features(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, np.int64))
    slot = m.add_keyframe(kf)
    hosted = m.points.add(slot, np.arange(6.0), np.arange(6.0) + 10, np.zeros(6, np.int64),
                          np.tile([0.0, 0.0, 1.0], (6, 1)), np.ones(6), np.ones(6),
                          np.ones(6), 10.0, 10.0, np.eye(4))
    m.obs.add(slot, hosted[:2], np.array([[0.0, 10.0], [1.0, 11.0]]), np.zeros(2, np.int64))
    m.points.delete(hosted[5:])
    m.points.status[hosted[4]] = CONVERGED
    seen, px = m.observed_by(slot)
    assert np.array_equal(seen, hosted[:5])
    assert np.array_equal(px, np.column_stack((np.arange(5.0), np.arange(5.0) + 10)))


def test_quality_as_in_thesis():
    cfg = TrackerConfig()
    assert classify(30, 100, cfg) == "good"  # ratio above 20 %
    assert classify(19, 100, cfg) == "bad"  # ratio below 20 % and fewer than 20 matches
    assert classify(25, 200, cfg) == "insufficient"
    assert classify(0, 0, cfg) == "bad"
    lost = LostCounter(cfg)
    assert [lost.update(q) for q in ("bad", "bad", "good", "bad", "bad", "bad")] == [
        False, False, False, False, False, True]


def _crowded_map(cam: CameraModel, spread: np.ndarray) -> tuple[Map, np.ndarray, Frame]:
    """A keyframe with six converged points in one 32 px cell and `spread` in cells of their
    own, and a current frame at the same pose and image (every match succeeds)."""
    m = Map(128, 96, 3, 5)
    image = np.random.default_rng(0).integers(0, 255, (96, 128), dtype=np.uint8)
    kf = Frame(0, 0.0, image, cam, 3)
    kf.T_c_w = np.eye(4)
    slot = m.add_keyframe(kf)
    crowded = np.array([[40.0 + k, 40.0 + k] for k in range(6)])  # six points in one cell
    px = np.vstack([crowded, spread])
    ids = m.points.add(slot, px[:, 0], px[:, 1], np.zeros(len(px), np.int64), cam.unproject(px),
                       np.ones(len(px)), np.full(len(px), 0.01), np.full(len(px), 2.0), 10.0,
                       10.0, np.eye(4))
    m.points.status[ids] = CONVERGED
    cur = Frame(1, 0.1, image, cam, 3)
    cur.T_c_w = np.eye(4)
    return m, ids, cur


SPREAD = np.array([[20.0, 20.0], [50.0, 70.0], [100.0, 20.0], [100.0, 70.0]])


def test_points_seen_for_keyframes_count_grid_cells():
    """The keyframe policy's count of points seen (Matches.n_visible) is the number of grid
    cells map points project into, not the points: points crowded into one cell (a camera
    climbing along its axis) count once, as tracking matches one point per cell."""
    cam = CameraModel(128, 96, 100.0, 100.0, 63.5, 47.5)
    config = TrackerConfig(grid_cell=32)
    m, ids, cur = _crowded_map(cam, SPREAD)
    reprojector = Reprojector(cam, config)
    n_visible = reprojector.run(cur, m, ids, np.zeros(len(ids), bool))[3]
    assert n_visible == 1 + len(SPREAD)
    # points not matched in kf_cell_max_unmatched frames in a row leave the count: a spread
    # point's cell goes, the crowded cell stays while one of its points is still matched
    m.points.n_unmatched[ids[-1]] = config.kf_cell_max_unmatched
    m.points.n_unmatched[ids[:5]] = config.kf_cell_max_unmatched + 3
    m.points.n_unmatched[ids[5]] = config.kf_cell_max_unmatched - 1
    assert reprojector.run(cur, m, ids, np.zeros(len(ids), bool))[3] == len(SPREAD)


def test_crowded_points_get_more_rounds_until_enough_match():
    """One point per cell (the thesis) matches the crowded cell once; while fewer than
    crowded_min_matches matched, each further round takes the next point of every cell, so
    a map crowded into a few cells (a take-off climb's zoom-out) keeps its matches."""
    cam = CameraModel(128, 96, 100.0, 100.0, 63.5, 47.5)

    def matched(least: int, spread: np.ndarray = SPREAD) -> int:
        m, ids, cur = _crowded_map(cam, spread)
        config = TrackerConfig(grid_cell=32, crowded_min_matches=least)
        return len(Reprojector(cam, config).run(cur, m, ids, np.zeros(len(ids), bool))[0])

    assert matched(0) == 1 + len(SPREAD)  # one per cell
    assert matched(7) == 7  # a round adds one (the crowded cell), the next reaches 7
    assert matched(50) == 6 + len(SPREAD)  # rounds until every point was tried
    # points about one per cell are not crowded (a turn leaves few points, each in its cell):
    # one round, however few matched
    wide = np.array([[10.0, 10.0], [70.0, 10.0], [100.0, 10.0], [10.0, 50.0], [70.0, 50.0],
                     [100.0, 50.0], [10.0, 80.0], [70.0, 80.0]])
    assert matched(50, wide) == 1 + len(wide)
