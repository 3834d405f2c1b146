"""Starting a map (thesis 6.6.1): feeding frames to the initialiser, the poses given before the
map exists (while the camera is at rest), and the initial map built from the initialiser's two
views; or, with depth (issue 30), the map of one frame and its measured depths."""

from __future__ import annotations

import time

import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.depth_filter import converged
from vo.depth_seeds import DepthSeeds, depth_seeds
from vo.frame import Frame
from vo.initialization import Initializer, InitialMap, InitOutcome
from vo.map import CONVERGED, Map
from vo.mapping import Mapper
from vo.matcher import inverse_depth_sigma
from vo.result import FrameResult, Quality, ms_since


class MapStart:
    """The initialiser of the next map, and the reference camera poses were given from."""

    def __init__(self, camera: CameraModel, config: TrackerConfig):
        self.camera = camera
        self.config = config
        self.initializer = Initializer(camera, config)
        self.posed_ref: Frame | None = None  # the initialiser reference poses were given from
        self.posed_t = -np.inf  # the time of the last frame given a pose from it

    def step(self, frame: Frame, timings: dict[str, float]) -> InitialMap | FrameResult:
        """Feed frame to the initialiser: the two views of a new map, or frame's result."""
        outcome = init_step(self.initializer, frame, timings)
        if isinstance(outcome, InitialMap):
            return outcome
        return self._pose_before_map(frame, outcome is InitOutcome.RESTART)

    def _pose_before_map(self, frame: Frame, is_reference: bool) -> FrameResult:
        """Before the map exists, the pose relative to the initialiser's reference (the future
        map's world frame) while the camera is at rest: the rotation that explains the tracks
        with the camera still at the reference's position (a translation too small to see;
        its covariance says how small). Only while the tracks have hardly moved at all: a
        sideways move over a distant flat scene shifts them like a turn does, so a rotation fit
        would hide it. The reference itself gets no pose: the initialiser may still replace
        it, and each posed reference would be a new map segment. Quality insufficient: no
        keyframe, no map."""
        init = self.initializer
        found = None if is_reference or not init.at_rest() else init.rotation_only()
        if found is None:
            return FrameResult(frame.t, None, Quality.INITIALIZING)
        R_cur_ref, rms = found
        T_w_c = np.eye(4)
        T_w_c[:3, :3] = R_cur_ref.T
        new_segment = self.posed_ref is not init.ref
        self.posed_ref, self.posed_t = init.ref, frame.t
        n = len(init.px_ref)
        cov = rotation_only_covariance(self.camera, init.px_ref, R_cur_ref, rms,
                                       self.config.init_ransac_px)
        return FrameResult(frame.t, T_w_c, Quality.INSUFFICIENT, covariance=cov, n_matches=n,
                           n_attempts=n, n_inliers=n, new_segment=new_segment)


def init_step(init: Initializer, frame: Frame, timings: dict[str, float],
              build: bool = True) -> InitialMap | InitOutcome:
    """Feed frame to an initialiser (restarting it from frame when needed); its outcome
    (`build`: see Initializer.add)."""
    t0 = time.perf_counter()
    outcome = init.add(frame, build) if init.ref is not None else InitOutcome.RESTART
    if outcome is InitOutcome.RESTART:
        init.set_reference(frame)
    timings["init"] = ms_since(t0)
    return outcome


def build_initial_map(map_: Map, ref: Frame, cur: Frame, init: InitialMap, px_angle: float,
                      config: TrackerConfig) -> int:
    """Two keyframes and their points from the initialiser's two views (`px_angle`: the
    angle of one pixel, for the points' depth uncertainty); returns the number of points."""
    pts = map_.points
    ref.T_c_w = np.eye(4)
    cur.T_c_w = init.T_cur_ref.copy()
    n = len(init.depth)
    level = np.zeros(n, dtype=np.int64)
    with map_.lock:
        slot = map_.add_keyframe(ref)
        rho = 1.0 / init.depth
        sigma = np.array([inverse_depth_sigma(init.T_cur_ref, init.f_ref[i], init.depth[i],
                                              px_angle) for i in range(n)])
        # no more uncertain than a new candidate's prior (points with little parallax)
        sigma = np.minimum(sigma, config.seed_sigma_ratio * np.median(rho))
        ids = pts.add(slot, init.px_ref[:, 0], init.px_ref[:, 1], level, init.f_ref, rho,
                      sigma, np.full(n, 2.0 * rho.max()), config.seed_a, config.seed_b,
                      np.eye(4))
        done = converged(rho, sigma, pts.pos_w[ids], np.zeros(3), cur.position,
                         config.convergence_L)
        pts.status[ids[done]] = CONVERGED
        pts.n_updates[ids[~done]] = config.candidate_min_updates
        ref.set_features(ids, init.px_ref, level)
        map_.obs.add(slot, ids, init.px_ref, level)
        cur.set_features(ids, init.px_cur, level.copy())
        map_.add_keyframe(cur)
    return n


def seeds_for_map(frame: Frame, mapper: Mapper, config: TrackerConfig) -> DepthSeeds | None:
    """The points a map started from frame's depth map alone would have: one corner per grid
    cell (as on a new keyframe) with a measured depth; None when fewer than init_min_inliers
    (a blank view, or the scene out of the depth camera's range)."""
    u, v, level = mapper.new_features(frame, np.zeros((0, 2)))
    px = np.column_stack((u, v))
    seeds = depth_seeds(frame.depth, px, level, frame.camera.unproject(px), config)
    return seeds if len(seeds) >= config.init_min_inliers else None


def build_depth_map(map_: Map, frame: Frame, seeds: DepthSeeds, config: TrackerConfig) -> int:
    """A map of one keyframe, `frame` (its camera is the world frame), and the points at their
    measured depths: metric from the first frame, no two-view initialisation. As the two-view
    map's points, they are candidates that tracking uses at once and the depth filter goes on
    refining (converging them at their first update when the sensor's sigma is small enough).
    Returns the number of points."""
    pts = map_.points
    frame.T_c_w = np.eye(4)
    frame.depth = None
    n = len(seeds)
    with map_.lock:
        slot = map_.add_keyframe(frame)
        ids = pts.add(slot, seeds.px[:, 0], seeds.px[:, 1], seeds.level, seeds.f, seeds.rho,
                      seeds.sigma, np.full(n, 2.0 * seeds.rho.max()), config.seed_a,
                      config.seed_b, np.eye(4))
        pts.n_updates[ids] = config.candidate_min_updates
        frame.set_features(ids, seeds.px, seeds.level)
        map_.obs.add(slot, ids, seeds.px, seeds.level)
    return n


def rotation_only_covariance(camera: CameraModel, px_ref: np.ndarray, R_cur_ref: np.ndarray,
                             rms_px: float, threshold_px: float) -> np.ndarray:
    """Covariance of a pose from a rotation-only fit (translation, rotation; world = reference
    camera, scene depth ~1 as the map will be scaled): a sideways move of d shifts the tracks by
    d * focal px, a move along the axis by d * focal * r (r = normalised radius), so an unseen
    move is below threshold_px over that; the rotation is known to rms_px / focal / sqrt(n)."""
    focal = float(np.sqrt(camera.fx * camera.fy))
    f = camera.unproject(px_ref)
    radius = float(np.median(np.linalg.norm(f[:, :2] / f[:, 2:], axis=1)))
    std_t = threshold_px / focal
    var_c = np.array([std_t, std_t, std_t / max(radius, 0.1)]) ** 2
    cov = np.zeros((6, 6))
    cov[:3, :3] = R_cur_ref.T @ np.diag(var_c) @ R_cur_ref
    cov[3:, 3:] = np.eye(3) * (max(rms_px, 0.1) / focal) ** 2 / len(px_ref)
    return cov
