"""Relocalisation by features: a lost frame's FAST corners are matched by ORB descriptor (thesis
6.5.1) to the map's points, and PnP with RANSAC on those matches (all, then those of the
keyframes hosting most) gives a pose. Direct alignment (vo.relocalization) needs a prior within
its basin; a view that turned or rolled far from every keyframe's still matches by descriptor,
which survives rotation in the image."""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np

from vo.frame import Frame
from vo.map_matching import MapMatcher
from vo.orb import VALID

PNP_ITERATIONS = 200
PNP_CONFIDENCE = 0.99
MIN_PNP_POINTS = 6  # below this solvePnPRansac has no minimal set to spare


class FeatureRelocalizer:
    """Poses for a lost frame from ORB matches to the matcher's map points and PnP."""

    def __init__(self, matcher: MapMatcher):
        self.matcher, self.config, self.map = matcher, matcher.config, matcher.map
        self._bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)

    def poses(self, frame: Frame) -> Iterator[np.ndarray]:
        """T_c_w candidates for frame: PnP on all its matches to the map's points, then on the
        matches to the points of each of the reloc_feature_keyframes keyframes hosting most;
        each with reloc_min_matches inliers."""
        cfg = self.config
        px, desc = self._frame_features(frame)
        ids, point_desc = self._map_points()
        if min(len(desc), len(ids)) < cfg.reloc_min_matches:
            return
        matches = [m for m in self._bf.match(desc, point_desc)
                   if m.distance <= cfg.reloc_orb_max_distance]
        if len(matches) < cfg.reloc_min_matches:
            return
        px = px[[m.queryIdx for m in matches]]
        ids = ids[[m.trainIdx for m in matches]]
        groups = [np.ones(len(ids), dtype=bool)]
        hosts = self.map.points.host[ids]
        slots, counts = np.unique(hosts, return_counts=True)
        for slot in slots[np.argsort(-counts, kind="stable")][:cfg.reloc_feature_keyframes]:
            groups.append(hosts == slot)
        for group in groups:
            T = self._pnp(px[group], ids[group])
            if T is not None:
                yield T

    def _frame_features(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """Level-0 pixels and ORB descriptors of the frame's level-0 FAST corners (described
        once per frame: Frame.orb)."""
        corners = frame.corners(self.config.fast_threshold, 0, 0)
        level0 = np.zeros(len(corners.x), dtype=bool)
        level0[corners.level_start[0]:corners.level_start[1]] = True
        frame.orb.fill(corners, level0)
        desc, state = frame.orb.tables(corners)
        ok = level0 & (state == VALID)
        return np.column_stack((corners.x[ok], corners.y[ok])).astype(np.float64), desc[ok]

    def _map_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The points tracking matches and their level-0 ORB descriptors at their host pixel
        (the map caches them: each point is described once)."""
        pts = self.map.points
        ids = self.matcher.usable_points()
        need = np.zeros((len(ids), pts.desc.shape[1]), dtype=bool)
        need[:, 0] = True
        self.map.describe_points(ids, need)
        ids = ids[pts.desc_state[ids, 0] == VALID]
        return ids, pts.desc[ids, 0]

    def _pnp(self, px: np.ndarray, ids: np.ndarray) -> np.ndarray | None:
        """T_c_w from pixels px of map points ids by PnP in RANSAC (the tracker's inlier
        threshold for this image's width); None with fewer than reloc_min_matches inliers."""
        cfg = self.config
        if len(ids) < max(cfg.reloc_min_matches, MIN_PNP_POINTS):
            return None
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            self.map.points.pos_w[ids], self.matcher.normalised(px), np.eye(3), None,
            iterationsCount=PNP_ITERATIONS, reprojectionError=self.matcher.ransac_px /
            self.matcher.focal, confidence=PNP_CONFIDENCE)
        if not ok or inliers is None or len(inliers) < cfg.reloc_min_matches:
            return None
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        return T
