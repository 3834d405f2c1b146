"""Relocalisation (thesis 6.9): while tracking is lost, find the frame's pose in the map by
aligning it to keyframes, newest first, from priors that phase correlation gives, or else from
ORB matches to the keyframes' points and PnP (vo.feature_relocalization), then matching the
map's points; a pose is accepted with enough inliers and a well determined rotation."""

from __future__ import annotations

import time

import cv2
import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.feature_relocalization import FeatureRelocalizer
from vo.frame import Frame
from vo.frame_alignment import align_frame
from vo.map_matching import MapMatcher, Matches
from vo.pose_optimizer import pose_covariance
from vo.result import Quality, ms_since
from vo.se3 import exp_se3, orthonormalized


class Relocalizer:
    """Looks for a lost frame's pose among the keyframes of the matcher's map."""

    def __init__(self, camera: CameraModel, config: TrackerConfig, matcher: MapMatcher):
        self.camera, self.config, self.matcher = camera, config, matcher
        self.map = matcher.map
        self.features = FeatureRelocalizer(matcher)
        # reloc_keyframes_per_frame: the next lost frame's share are keyframes older than this
        # id (by id, not position: the mapping can add or cull keyframes while lost)
        self.older_than = np.inf

    def restart(self) -> None:
        """A new loss: the next lost frame's share starts at the newest keyframe."""
        self.older_than = np.inf

    def find(self, frame: Frame, timings: dict[str, float], last: Frame | None = None
             ) -> tuple[Matches, np.ndarray] | None:
        """The first reference that gives frame a pose: the last tracked frame `last` (a fast
        turn loses the track where the camera still stands, often far from any keyframe),
        then the keyframes, newest first, by direct alignment; then (reloc_features) the
        keyframes by ORB matches and PnP. With reloc_keyframes_per_frame, this frame's share
        of that (see _share). Returns the matches (the refined pose in them) and the pose's
        covariance; None when no reference does."""
        t0 = time.perf_counter()
        found = None
        for T in self._priors(frame, last):
            frame.T_c_w = T
            found = self._verified(frame)
            if found is not None:
                break
        timings["relocalize"] = ms_since(t0)
        return found

    def _priors(self, frame: Frame, last: Frame | None):
        """Pose priors for frame, in the order find tries them: direct alignment to each
        reference that explains its patches well enough, then (reloc_features) PnP on ORB
        matches."""
        cfg = self.config
        slots, features = self._share()
        for ref, ids, px in self._references(last, slots):
            if self._align_to_reference(frame, ref, ids, px) < cfg.reloc_max_residual_ratio:
                yield frame.T_c_w
        if cfg.reloc_features and features:
            yield from self.features.poses(frame)

    def _share(self) -> tuple[list[int], bool]:
        """The keyframe slots this lost frame aligns to, newest first (at most
        reloc_max_keyframes, 0 = all), and whether it tries the ORB step: all of them and yes,
        or with reloc_keyframes_per_frame the next share older than the last one, and the ORB
        step without keyframes once every share was tried (the last tracked frame is tried on
        every lost frame)."""
        cfg = self.config
        slots = sorted(self.map.keyframes, key=lambda s: -self.map.keyframes[s].id)
        if cfg.reloc_max_keyframes > 0:
            slots = slots[:cfg.reloc_max_keyframes]
        n = cfg.reloc_keyframes_per_frame
        if n <= 0:
            return slots, True
        older = [s for s in slots if self.map.keyframes[s].id < self.older_than]
        if not older:
            self.older_than = np.inf
            if cfg.reloc_features:
                return [], True
            older = slots
        share = older[:n]
        self.older_than = self.map.keyframes[share[-1]].id if share else np.inf
        return share, False

    def _verified(self, frame: Frame) -> tuple[Matches, np.ndarray] | None:
        """The map's points matched from frame's pose prior, refined: with its covariance when
        they are reloc_min_matches inliers, not of bad quality, and the rotation well
        determined; else None."""
        cfg = self.config
        m = self.matcher.match(frame, {})
        if m.n_inliers < cfg.reloc_min_matches or self.matcher.quality(m) == Quality.BAD:
            return None
        cov = pose_covariance(m.H, m.sigma, orthonormalized(m.T))
        return (m, cov) if _rotation_std_deg(cov) <= cfg.reloc_max_rotation_std_deg else None

    def _references(self, last: Frame | None, slots: list[int]):
        """(frame, point ids, level-0 pixels) to align a lost frame to: the last tracked frame
        and its matched points (with reloc_last_frame, unless it is a keyframe), then the
        keyframes in `slots`."""
        if self.config.reloc_last_frame and last is not None and not last.is_keyframe:
            yield last, last.feat_point, last.feat_px
        for slot in slots:
            yield (self.map.keyframes[slot], *self.map.observed_by(slot))

    def _align_to_reference(self, frame: Frame, kf: Frame, ids: np.ndarray,
                            px: np.ndarray) -> float:
        """Frame's pose by direct alignment to reference kf (its points ids seen at pixels px)
        from the best of the shifted priors; returns the residual ratio of that alignment."""
        X = self.map.points.pos_w[ids] @ kf.T_c_w[:3, :3].T + kf.T_c_w[:3, 3]
        depth = float(np.median(X[:, 2])) if len(X) else 1.0
        cfg = self.config
        best, best_T = np.inf, kf.T_c_w
        for prior, turned in shifted_priors(kf, frame, self.camera, cfg.reloc_shift_level,
                                            depth):
            frame.T_c_w = prior
            if turned and cfg.reloc_rotation_first:
                # a turn (a fast rotation lost the track) also rolls, which no image shift
                # shows: find the whole rotation first, where the camera stood
                align_frame(frame, kf, ids, px, self.map.points, self.camera, cfg,
                            rotation_only=True)
            ratio = align_frame(frame, kf, ids, px, self.map.points, self.camera, cfg,
                                measure=True)
            if ratio < best:
                best, best_T = ratio, frame.T_c_w
        frame.T_c_w = best_T
        return best


def shifted_priors(kf: Frame, frame: Frame, camera: CameraModel, level: int,
                   depth: float) -> list[tuple[np.ndarray, bool]]:
    """T_c_w priors for frame from the keyframe's pose and the image shift that phase
    correlation finds between the two images at pyramid `level` (the view may be far outside
    the basin of direct alignment): the keyframe turned, and the keyframe moved sideways
    (scene at `depth`), so that its image moves by that shift; each with whether it is the
    turn."""
    a = np.float32(kf.pyr.images[level])
    b = np.float32(frame.pyr.images[level])
    (du, dv), _ = cv2.phaseCorrelate(a - a.mean(), b - b.mean())
    # the correlation is circular: a shift by more than half the image (a view that overlaps
    # the keyframe by less than half) shows up wrapped, so its unwrapped twin is tried too
    priors = []
    for su in (du, du - np.sign(du) * a.shape[1]):
        for sv in (dv, dv - np.sign(dv) * a.shape[0]):
            turn, move = _shift_priors(kf.T_c_w, camera, su * 2.0 ** level,
                                       sv * 2.0 ** level, depth)
            priors += [(turn, True), (move, False)]
    return priors


def _shift_priors(T_c_w: np.ndarray, camera: CameraModel, du: float, dv: float,
                  depth: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose T_c_w turned, and moved sideways (scene at `depth`), so that its image content
    shifts by (du, dv) pixels."""
    # content moves by +du when the camera turns by du / f about its y axis, or moves by
    # -du * depth / f along its x axis
    turn = np.array([0.0, 0.0, 0.0, -np.arctan(dv / camera.fy), np.arctan(du / camera.fx), 0.0])
    move = np.eye(4)
    move[:3, 3] = (du * depth / camera.fx, dv * depth / camera.fy, 0.0)
    return exp_se3(turn) @ T_c_w, move @ T_c_w


def _rotation_std_deg(cov: np.ndarray | None) -> float:
    """The largest rotation standard deviation (degrees) of a pose covariance (inf if none)."""
    if cov is None:
        return np.inf
    return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:])[-1], 0.0))))
