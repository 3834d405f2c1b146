"""ORB matching (6.5.1): OpenCV's descriptors on our keypoints, each computed once; the epipolar
search finds the true correspondence by Hamming distance; the tracker runs with matcher "orb"."""

from __future__ import annotations

import hashlib
from collections import Counter

import cv2
import numpy as np
import pytest
from vo_scenes import pair_truth, sample_corners, textured_pair

import vo.orb
from sdvl.errors import InputError
from sim.metrics import evaluate
from sim.trajectory import Trajectory
from vo.config import TrackerConfig
from vo.matcher import match_epipolar
from vo.orb import VALID, OrbQuery, describe, describe_levels, hamming, orientations, query
from vo.tracker import Tracker


@pytest.fixture(scope="module")
def pair(data_dir):
    return textured_pair(data_dir)


def _texture(seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 255, (120, 160)).astype(np.uint8), (5, 5), 0)


def test_descriptors_are_opencv_orb_and_hamming_counts_bits():
    img = _texture()
    x = np.array([40.0, 80.0, 3.0, 150.0])
    y = np.array([50.0, 60.0, 60.0, 110.0])
    desc, state = describe(img, x, y)
    assert list(state) == [VALID, VALID, vo.orb.NONE, vo.orb.NONE]  # the last two: border
    angle = orientations(img, x[:2], y[:2])
    orb = cv2.ORB_create(nlevels=1, edgeThreshold=vo.orb.EDGE, patchSize=31)
    _, ref = orb.compute(img, [cv2.KeyPoint(40.0, 50.0, 31, angle[0]),
                               cv2.KeyPoint(80.0, 60.0, 31, angle[1])])
    assert np.array_equal(desc[:2], ref)
    slow = sum(bin(int(a) ^ int(b)).count("1") for a, b in zip(desc[0], desc[1], strict=True))
    assert hamming(desc[0], desc[1]) == slow == cv2.norm(desc[0], desc[1], cv2.NORM_HAMMING)


def test_orientation_is_the_intensity_centroid_and_follows_a_rotation():
    img = _texture(4)
    x, y = np.array([50.0, 77.4, 100.0]), np.array([40.0, 61.6, 80.0])
    r = vo.orb.PATCH_SIZE // 2
    for k, angle in enumerate(orientations(img, x, y)):  # slow reference
        cx, cy = round(x[k]), round(y[k])
        dv, du = np.mgrid[-r:r + 1, -r:r + 1]
        disc = du ** 2 + dv ** 2 <= r * r + 0.5
        patch = img[cy - r:cy + r + 1, cx - r:cx + r + 1].astype(float)
        slow = np.degrees(np.arctan2((dv * patch)[disc].sum(), (du * patch)[disc].sum())) % 360
        assert angle == pytest.approx(slow, abs=1e-9)
    # the image turned by 90 degrees: orientations turn with it and descriptors still match
    turned = np.ascontiguousarray(np.rot90(img))  # pixel (x, y) moves to (y, W - 1 - x)
    xt, yt = y, img.shape[1] - 1 - x
    assert (orientations(img, x, y) - orientations(turned, xt, yt)) % 360 == pytest.approx(
        [90.0] * 3, abs=1e-6)
    a, b = describe(img, x, y)[0], describe(turned, xt, yt)[0]
    same = [hamming(a[k], b[k]) for k in range(3)]
    other = [hamming(a[k], b[(k + 1) % 3]) for k in range(3)]
    assert max(same) <= 10 and min(other) > 80


def test_corner_descriptors_are_computed_once_and_shared(pair, monkeypatch):
    _, _, cur, _, _ = pair
    described = []
    real = vo.orb.describe

    def counting(image, x, y):
        described.extend((image.shape, a, b) for a, b in zip(x, y, strict=True))
        return real(image, x, y)

    monkeypatch.setattr(vo.orb, "describe", counting)
    coarse = cur.corners(10, 1)  # tracking's corners (levels >= 1)
    full = cur.corners(10, 0)  # mapping's corners (all levels)

    def middle(c, level, n):  # n corners from the middle rows of a level (away from borders)
        lo, hi = c.level_start[level], c.level_start[level + 1]
        return np.arange(n) + (lo + hi) // 2

    need = np.zeros(len(coarse.x), dtype=bool)
    need[middle(coarse, 1, 30)] = True
    cur.orb.fill(coarse, need)
    need[middle(coarse, 2, 10)] = True
    cur.orb.fill(coarse, need)  # the first 30 are cached: only 10 new ones
    assert len(described) == cur.orb.computed == 40
    # mapping's corners see the same descriptors, and compute only what is new
    a, b = middle(coarse, 1, 30), middle(full, 1, 30)
    assert np.all(cur.orb.tables(full)[1][b] != vo.orb.UNKNOWN)
    assert np.array_equal(cur.orb.tables(full)[0][b], cur.orb.tables(coarse)[0][a])
    assert np.array_equal(cur.orb.tables(full)[0][b],
                          describe(cur.pyr.images[1], coarse.x[a], coarse.y[a])[0])
    need = np.zeros(len(full.x), dtype=bool)
    need[middle(full, 1, 35)] = True
    cur.orb.fill(full, need)
    assert len(described) == 45 and len(set(described)) == 45


def _epipolar_orb(cam, ref, cur, px, f, rho, T_cur_ref):
    """ORB epipolar search of every reference pixel: a pass that collects the descriptors it
    needs, then the matching pass. Returns matches (u, v, ok) and the passes' pending counts."""
    levels = 5
    desc = np.zeros((len(px), levels, 32), dtype=np.uint8)
    state = np.zeros((len(px), levels), dtype=np.int8)

    def fill_refs(rows, need):
        d, s = desc[rows], state[rows]
        describe_levels(ref.pyr.images, px[rows, 0], px[rows, 1], need, d, s)
        desc[rows], state[rows] = d, s

    c = cur.corners(10)
    orb = OrbQuery(100, np.arange(len(px)), desc, state, levels, cur.orb, c, fill_refs)
    pending, out = [], []
    for _ in range(2):
        out = []
        for i in range(len(px)):
            out.append(match_epipolar(
                cam.params, ref.pyr.layout, ref.pyr.flat, (px[i, 0], px[i, 1], 0, f[i]),
                rho[i] * 1.2, rho[i] * 0.5, T_cur_ref, cur.pyr.flat, c.tables,
                (0, 2, 2.0, 2000.0, 10), query(orb.tables, i)))
        pending.append(int(orb.pending[0]))
        orb.fill()
    return out, pending


def test_orb_epipolar_search_finds_the_true_corner(pair):
    cam, ref, cur, T_ref, T_cur_ref = pair
    px = sample_corners(cam, ref)
    f, d, true = pair_truth(cam, T_ref, T_cur_ref, px)
    visible = cam.in_image(true, 20)
    out, pending = _epipolar_orb(cam, ref, cur, px, f, 1.0 / d, T_cur_ref)
    assert pending[0] > 0 and pending[1] == 0  # one collecting pass was enough
    hits = [np.hypot(u - true[i, 0], v - true[i, 1]) for i, (u, v, _, ok) in enumerate(out)
            if ok and visible[i]]
    assert len(hits) >= 20
    assert np.mean(np.array(hits) < 0.3) >= 0.8
    # only corners near some epipolar segment were described, not the whole frame
    assert cur.orb.computed < 0.5 * len(cur.corners(10).x)


def test_config_selects_the_matcher():
    assert TrackerConfig().matcher == "patch"
    assert TrackerConfig.from_dict({"matcher": "orb"}).orb_max_distance == 100
    with pytest.raises(InputError, match="matcher"):
        TrackerConfig(matcher="sift")
    # ORB tracking searches full-resolution corners too; patch tracking from its own level
    assert TrackerConfig(matcher="orb").track_corner_level == 0
    assert TrackerConfig().track_corner_level == TrackerConfig().track_search_min_level == 1
    with pytest.raises(InputError, match="orb_track_min_level"):
        TrackerConfig(orb_track_min_level=3)


def test_tracker_with_orb_matching(data_dir, monkeypatch):
    """The first 120 VAMR frames with ORB matching: accurate, and no corner and no map point
    is described twice at the same place of the same image."""
    from sim.datasets import open_sequence

    keys: Counter = Counter()
    real = vo.orb.describe

    def recording(image, x, y):
        digest = hashlib.blake2b(image.tobytes(), digest_size=8).digest()
        keys.update((digest, round(a, 3), round(b, 3)) for a, b in zip(x, y, strict=True))
        return real(image, x, y)

    monkeypatch.setattr(vo.orb, "describe", recording)
    seq = open_sequence(data_dir / "vamr_ex01_checkerboard736")
    tracker = Tracker(seq.camera, TrackerConfig(matcher="orb"))
    t, T = [], []
    for stamp, image in seq.frames(120):
        r = tracker.process(image, stamp)
        if r.has_pose:
            t.append(stamp)
            T.append(r.T_w_c)
    assert len(t) >= 105
    ev = evaluate(seq.groundtruth, Trajectory.from_matrices(np.array(t), np.array(T)), "sim3")
    assert ev.ate_rmse_m < 0.01
    assert len(keys) > 1000
    # a new keyframe's features are described for the map and may be described again as
    # corners when that keyframe is searched: at most twice, and rarely
    repeats = sum(n > 1 for n in keys.values())
    assert max(keys.values()) <= 2 and repeats < 0.1 * len(keys)
