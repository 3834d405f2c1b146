"""Map merging (issue 31): a map that re-initialisation replaced is kept, and the frames tracked
in the new map keep trying to relocalise into it (vo.relocalization, with its own matcher).
Two relocalisations that agree on the similarity between the maps join them: the old map's
keyframes and points are moved into the new map's world (rotation, translation and scale) and
added to it, so the flight goes on in one map that knows both places, and the poses given in
the old map can be re-expressed in the new one (FrameResult.merged).

The scale between two monocular maps is not in one pose: it comes from the depths of the old
map's matched points against the new map's points seen near them in the same frame. A join is
as good as each map's own drift at the joining frame: nothing bends the two maps together
afterwards (RESULTS.md: tracker-map-merge)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.map import CANDIDATE, CONVERGED, Map
from vo.map_matching import MapMatcher, Matches
from vo.relocalization import Relocalizer
from vo.reprojector import Reprojector
from vo.se3 import inv_se3, orthonormalized, rotation_angle_deg


@dataclass
class Similarity:
    """x_new = scale * R @ x_old + t: the old map's world in the new map's."""

    R: np.ndarray
    t: np.ndarray
    scale: float

    def pose(self, T_w_c: np.ndarray) -> np.ndarray:
        """A world-from-camera pose of the old map in the new map's world."""
        out = np.eye(4)
        out[:3, :3] = self.R @ T_w_c[:3, :3]
        out[:3, 3] = self.scale * self.R @ T_w_c[:3, 3] + self.t
        return out


@dataclass
class Retired:
    """A map re-initialisation replaced, and what relocalises frames into it: by direct
    alignment alone (~10 ms a try on tum_fr1_rpy), and also by ORB features and PnP (~40 ms
more)."""

    map: Map
    direct: Relocalizer
    features: Relocalizer
    last: Frame | None


def similarity(T_c_w_old: np.ndarray, T_c_w_new: np.ndarray, scale: float) -> Similarity:
    """The similarity that puts one camera's pose in the old map onto its pose in the new one,
    with the new map's units `scale` times the old map's."""
    R_o, t_o = T_c_w_old[:3, :3], T_c_w_old[:3, 3]
    R_n, t_n = T_c_w_new[:3, :3], T_c_w_new[:3, 3]
    return Similarity(R_n.T @ R_o, R_n.T @ (scale * t_o - t_n), scale)


def depth_ratio(old_depth: np.ndarray, old_uv: np.ndarray, new_depth: np.ndarray,
                new_uv: np.ndarray, radius_px: float, min_pairs: int) -> float:
    """New-map units per old-map unit from one frame's depths: per old point, the median depth
    of the new map's points within radius_px of it over its own, the median over points
    (with fewer than min_pairs such points, the ratio of the two medians). NaN without any."""
    if len(old_depth) == 0 or len(new_depth) == 0:
        return np.nan
    d2 = ((old_uv[:, None, :] - new_uv[None, :, :]) ** 2).sum(axis=2)
    near = d2 < radius_px ** 2
    has = near.any(axis=1)
    if has.sum() < min_pairs:
        return float(np.median(new_depth) / np.median(old_depth))
    ratios = [np.median(new_depth[near[k]]) / old_depth[k] for k in np.flatnonzero(has)]
    return float(np.median(ratios))


def agree(a: Similarity, b: Similarity, at: np.ndarray, depth: float, cfg: TrackerConfig
          ) -> bool:
    """Whether two estimates of the similarity are the same one: turned by at most
    merge_max_turn_deg, scales within merge_scale_tolerance, and the old map's point `at`
    (where a frame saw the scene, `depth` new units from it) put within merge_max_move_depths
    depths of each other."""
    turn = rotation_angle_deg(a.R @ b.R.T)
    ratio = max(a.scale, b.scale) / min(a.scale, b.scale)
    moved = float(np.linalg.norm((a.scale * a.R @ at + a.t) - (b.scale * b.R @ at + b.t)))
    return (turn <= cfg.merge_max_turn_deg and ratio <= 1.0 + cfg.merge_scale_tolerance
            and moved <= cfg.merge_max_move_depths * depth)


class MapMerger:
    """Keeps the map re-initialisation replaced and joins it to the current one."""

    def __init__(self, camera: CameraModel, config: TrackerConfig, reprojector: Reprojector):
        self.camera, self.config, self.reprojector = camera, config, reprojector
        # relocalisation into the old map for merging: a weaker match count than for a lost
        # frame, as two relocalisations must agree on the whole similarity; tries come seconds
        # apart, so each tries every keyframe
        self.reloc_config = replace(config, reloc_min_matches=config.merge_min_matches,
                                    reloc_keyframes_per_frame=0)
        self.retired: Retired | None = None
        self.estimate: Similarity | None = None
        self.last_try = -np.inf
        self.tries = 0
        self.merged: Similarity | None = None  # done, not yet reported (take_merged)
        self.metric = False  # the maps are from depth maps: scale 1

    def retire(self, map_: Map, last: Frame | None, metric: bool) -> None:
        """Keep a map re-initialisation is replacing (the newest one only; a map of fewer
        than two keyframes leaves the one kept before); `metric`: maps from depth maps."""
        self.estimate, self.metric = None, metric
        if not self.config.merge_maps or len(map_) < 2:
            return
        matcher = MapMatcher(self.camera, self.reloc_config, map_, self.reprojector)
        direct = replace(self.reloc_config, reloc_features=False)
        self.retired = Retired(map_, Relocalizer(self.camera, direct, matcher),
                               Relocalizer(self.camera, self.reloc_config, matcher), last)
        self.tries = 0

    def take_merged(self) -> Similarity | None:
        """The similarity of a merge done since the last call (None if none)."""
        merged, self.merged = self.merged, None
        return merged

    def step(self, frame: Frame, current: Map) -> None:
        """Try to relocalise a frame tracked in the current map into the retired one (at
        most every period()), and merge them when two tries agree."""
        if self.retired is None or frame.t - self.last_try < self.period():
            return
        self.last_try = frame.t
        found = self._relocalise(frame, current)
        if found is None:
            return
        S, at, depth = found
        if self.estimate is not None and agree(self.estimate, S, at, depth, self.config):
            with current.lock:
                absorb(current, self.retired.map, S, self.config.max_keyframes)
                self.merged = S  # taken by the tracker under the same lock
            self.retired, self.estimate = None, None
            return
        self.estimate = S

    def period(self) -> float:
        """Seconds between tries: merge_period_s, doubled after every merge_backoff_tries
        tries (a view that has not come back for a while costs less), at most
        merge_period_max_s."""
        cfg = self.config
        doubled = cfg.merge_period_s * 2.0 ** (self.tries // cfg.merge_backoff_tries)
        return min(doubled, max(cfg.merge_period_max_s, cfg.merge_period_s))

    def _relocalise(self, frame: Frame, current: Map
                    ) -> tuple[Similarity, np.ndarray, float] | None:
        """The similarity from frame's pose in the retired map, where in the old map the
        frame's matched points lie (their centroid) and their depth in new units; None when
        it does not relocalise or shows no scale."""
        probe = Frame(frame.id, frame.t, frame.pyr.images[0], self.camera,
                      self.config.pyramid_levels)
        every = self.config.merge_features_every
        features = self.config.reloc_features and every > 0 and self.tries % every == 0
        self.tries += 1
        reloc = self.retired.features if features else self.retired.direct
        found = reloc.find(probe, {}, self.retired.last)
        if found is None:
            return None
        m: Matches = found[0]
        T_old = orthonormalized(m.T)
        old_pos = self.retired.map.points.pos_w[m.ids[m.inlier]]
        old_cam = old_pos @ T_old[:3, :3].T + T_old[:3, 3]
        new_pos = current.points.pos_w[frame.feat_point]
        new_cam = new_pos @ frame.T_c_w[:3, :3].T + frame.T_c_w[:3, 3]
        scale = 1.0 if self.metric else depth_ratio(
            np.linalg.norm(old_cam, axis=1), m.uv[m.inlier], np.linalg.norm(new_cam, axis=1),
            frame.feat_px, self.config.merge_depth_radius_px, self.config.merge_min_pairs)
        if not np.isfinite(scale) or scale <= 0 or len(new_cam) == 0:
            return None
        depth = float(np.median(np.linalg.norm(new_cam, axis=1)))
        return similarity(T_old, frame.T_c_w, scale), old_pos.mean(axis=0), depth


def absorb(dst: Map, src: Map, S: Similarity, max_keyframes: int) -> dict[int, int]:
    """Add src's keyframes with their live points and observations to dst, moved by S into
    dst's world. Of both maps' keyframes, the max_keyframes nearest to dst's newest one are
    kept (the map's own cap drops the farthest too): dst's others are removed. Returns src
    slot -> dst slot."""
    newest = max(dst.keyframes.values(), key=lambda kf: kf.id, default=None)
    here = newest.position if newest is not None else np.zeros(3)
    moved = {slot: S.pose(kf.T_w_c) for slot, kf in src.keyframes.items()}
    both = [(float(np.linalg.norm(T[:3, 3] - here)), "src", s) for s, T in moved.items()]
    both += [(float(np.linalg.norm(kf.position - here)), "dst", s)
             for s, kf in dst.keyframes.items() if kf is not newest]
    both.sort(key=lambda row: row[0])
    kept = both[:max(max_keyframes - (newest is not None), 0)]
    for _, side, s in both[len(kept):]:
        if side == "dst":
            dst.remove_keyframe(s)
    slots = {}
    for _, side, s in kept:
        if side == "src":
            kf = src.keyframes[s]
            kf.T_c_w = inv_se3(moved[s])
            if kf.pose_info is not None:
                kf.pose_info = _scaled_info(kf.pose_info, S.scale)
            slots[s] = dst.add_keyframe(kf, observations=False)
    ids = _copy_points(dst, src, slots, S.scale)
    rows = np.isin(src.obs.kf, list(slots)) & (ids[src.obs.point] >= 0)
    for s, d in slots.items():
        mine = rows & (src.obs.kf == s)
        dst.obs.add(d, ids[src.obs.point[mine]], src.obs.uv[mine], src.obs.level[mine])
        kf = dst.keyframes[d]
        keep = ids[kf.feat_point] >= 0
        kf.feat_point, kf.feat_px = ids[kf.feat_point[keep]], kf.feat_px[keep]
        kf.feat_level = kf.feat_level[keep]
    return slots


def _copy_points(dst: Map, src: Map, slots: dict[int, int], scale: float) -> np.ndarray:
    """Copy src's live points hosted by the keyframes in `slots` into dst (inverse depths in
    dst's units); per src point its dst id (-1: not copied)."""
    sp, dp = src.points, dst.points
    status = sp.status[: sp.capacity]
    host = sp.host[: sp.capacity]
    keep = ((status == CANDIDATE) | (status == CONVERGED)) & np.isin(host, list(slots))
    old = np.flatnonzero(keep)
    ids = np.full(sp.capacity, -1, dtype=np.int64)
    if len(old) == 0:
        return ids
    new = dp.alloc(len(old))
    ids[old] = new
    for name in ("status", *sp.FLOAT_COLS, *sp.INT_COLS, "f", "desc", "desc_state"):
        getattr(dp, name)[new] = getattr(sp, name)[old]
    for name in ("rho", "sigma", "rho_range"):  # inverse depths: host-camera units shrink
        getattr(dp, name)[new] /= scale
    to_dst = np.full(len(src.kf_pyr), -1, dtype=np.int64)
    to_dst[list(slots)] = list(slots.values())
    dp.host[new] = to_dst[sp.host[old]]
    for d in set(slots.values()):
        mine = new[dp.host[new] == d]
        dp.update_positions(mine, dst.keyframes[d].T_w_c)
    return ids


def _scaled_info(info: np.ndarray, scale: float) -> np.ndarray:
    """A pose's information (translation, rotation) with translations `scale` times longer."""
    out = info.copy()
    out[:3, :] /= scale
    out[:, :3] /= scale
    return out
