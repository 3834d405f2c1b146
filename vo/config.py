"""Every tracker parameter in one place, with the thesis defaults (Perdices 2017, ch. 6-7)."""

from __future__ import annotations

import importlib.util
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sdvl.errors import InputError
from sdvl.tables import check_limits, dataclass_from_table, read_toml
from vo.config_limits import LIMITS

GTSAM_MISSING = ("ba_method = 'gtsam' needs the gtsam package: pip install "
                 "'sdvl-companion[gtsam]' (or set ba_method = 'trf')")


@dataclass
class TrackerConfig:
    """Parameters of the SDVL tracker; pixel quantities are at pyramid level 0."""

    # frames (6.2, 6.4)
    pyramid_levels: int = 5
    fast_threshold: int = 10
    # one match per cell in tracking, one new point per empty cell of a keyframe; 16 px cells
    # did better on walkers at 320x240 but worse on the sliding board of
    # test_vo_outlier_rejection and tracked 1.5x slower (RESULTS.md: tracker-grid-cell)
    grid_cell: int = 32

    # sparse image alignment (6.7.1)
    align_max_level: int = 4
    align_min_level: int = 2
    align_iterations: int = 30
    # Tukey-weighted intensity residuals (vo.sparse_align), else plain least squares (6.10):
    # a few patches that no longer fit their reference pulled the pose (RESULTS.md:
    # tracker-align-robust)
    align_robust: bool = True

    # feature alignment and pose refinement (6.7.2, 6.7.3)
    max_matches: int = 200
    # while the visible points crowd into fewer cells than this (two or more per cell) and
    # fewer matched, another round takes the next point of each cell (a take-off climb's 10x
    # zoom-out left 8 of 62 points to try and lost its map); 0, one per cell as in the thesis:
    # seed_unmatched_prior keeps that map (50: RESULTS.md, tracker-crowded-cells)
    crowded_min_matches: int = 0
    align2d_iterations: int = 10
    track_candidates: bool = True
    candidate_min_updates: int = 3
    # a map point is dropped after this many failed matches (and more failures than finds)
    point_max_missed: int = 10
    # search along the epipolar segment when direct alignment of a converged point fails
    track_search_fallback: bool = True
    # tracking searches FAST corners from this level up (then refines at level 0), so it does
    # not wait for full-resolution FAST; mapping searches from level 0
    track_search_min_level: int = 1
    pose_iterations: int = 10
    reprojection_inlier_px: float = 2.0
    constant_velocity: bool = True
    # the camera's turn between frames from the caller (the autopilot's attitude, rotation
    # prior): per-frame std of what a rigidly mounted camera's attitude gets wrong (interpolated
    # 50 Hz attitude, a 10 ms clock error at 200 deg/s^2: ~0.07 deg) plus the caller's own
    # variance; 0 = not used. A downward camera over flat ground cannot tell a small tilt from
    # a sideways move (RESULTS.md: tracker-rotation-prior)
    rotation_prior_deg: float = 0.1
    # the prior is not used in a frame whose image alignment turned this far from it (a wrong
    # mounting, a time error)
    rotation_prior_gate_deg: float = 3.0

    # outlier rejection (6.8): RANSAC over 5-point subsets of the matches, inliers within
    # ransac_threshold_px (image pixels), hypotheses for ransac_probability at most
    # ransac_max_hypotheses; then outliers within ransac_rescue_px of the inlier pose rejoin.
    # On by default: kitti00 0.77 m mean over tracker seeds 0-9 (2.79 m off at seed 0), tum
    # 687/723 (RESULTS.md: tracker-rejection-default, tracker-ransac-width)
    outlier_rejection: bool = True
    ransac_threshold_px: float = 2.0
    ransac_rescue_px: float = 4.0
    # both are pixels of an image this wide, and grow with a wider one (the same blur and
    # coarse-level search span more of its pixels), never shrink below them (a pixel of a
    # smaller image is already coarse next to the matches' noise): a 1241-pixel car camera
    # judges at 3.9 / 7.8 px: kitti00 0.86 -> 0.77 m mean over tracker seeds 0-9 (seed 0: 1.13
    # -> 0.64 m), where its preset had to set 4 / 8 (RESULTS.md: tracker-ransac-width)
    ransac_reference_width_px: int = 640
    ransac_probability: float = 0.99
    ransac_max_hypotheses: int = 100
    # RANSAC and the rescue judge a match's error whitened for its point's depth uncertainty
    # (as the pose refinement does): candidates still uncertain in depth are not rejected for
    # lying along their epipolar segments (kitti00 at 5 Hz keeps its map; at 10 Hz better on 7
    # of 10 seeds, one ran off to 6.4 m), but neither are movers whose depth never converges
    # (walkers, the sliding board: tests/test_vo_outlier_rejection.py), hence off (RESULTS.md:
    # tracker-ransac-whitened)
    ransac_depth_whitening: bool = False
    # ... with it, above 0: only candidates whose depth filter holds them at least this likely
    # inliers (a / (a + b)) are judged whitened; 0.5 kept movers out, helped kitti00 (6 of 10
    # seeds), not tum or the synthetic presets (RESULTS.md: tracker-ransac-gate-*)
    ransac_whitening_min_inlier: float = 0.0
    # the rescue judges candidates whitened for their depth (converged points plain), with
    # rescue_whitening_min_inlier above 0 only those their filter holds at least that likely
    # inliers: on tum_fr1_rpy newly converged points outvoted 70-80 candidates and a well
    # tracked turn was lost. On, tum keeps one map on 5 of 10 tracker seeds (2 off), but the
    # synthetic presets lose 30-65% in ATE and the walkers come back into the pose (gate 0), or
    # kitti00 loses 21% (0.5): off (RESULTS.md: tracker-rescue-whitened)
    rescue_depth_whitening: bool = False
    rescue_whitening_min_inlier: float = 0.0
    # a bad frame whose pose enough matches agree with along their depth intervals (the
    # segment of the epipolar line a 2-sigma interval projects to; out to infinity it allows
    # any move) is held: tracked on from, not published, not a step towards lost, within
    # hold_max_s of the last published frame (ArduPilot's AP_VISUALODOM_TIMEOUT_MS, 300 ms:
    # longer, the autopilot holds vision unhealthy anyway). tum_fr1_rpy's fast turns
    # (RESULTS.md: tracker-hold)
    hold_frames: bool = True
    hold_max_s: float = 0.3
    # with outlier rejection, a point matched but rejected this many tracked frames in a row
    # leaves the map (a person who stood while mapped and walked off: its many finds kept it
    # first in its grid cell); 10 kept such points too long (RESULTS.md:
    # tracker-point-max-rejected)
    point_max_rejected: int = 3

    # quality (6.10)
    quality_min_ratio: float = 0.2
    quality_min_matches: int = 20
    lost_after_bad: int = 3
    reinit_when_lost: bool = True

    # relocalisation (6.9): while lost, keyframes are tried newest first (direct alignment,
    # then point matching); one is accepted with this many inlier matches
    relocalize: bool = True
    reloc_min_matches: int = 20
    # direct alignment to a keyframe must explain the patches this well before matching
    # (zero-mean residual over patch energy: 0 perfect, ~1 blank image, ~2 unrelated texture);
    # 1.0 let poses 40-120 deg off through on kitti00 and tum_fr1_rpy, also with the
    # confirmation below (RESULTS.md: tracker-reloc-verify)
    reloc_max_residual_ratio: float = 0.5
    # pyramid level at which the image shift to a keyframe is found (phase correlation)
    reloc_shift_level: int = 2
    # a relocalised pose must be this well determined (largest rotation std of its covariance,
    # degrees): matches crowded into the sliver of view shared with a keyframe leave tilt and
    # sideways position confused (seen: 14 deg and 2.7 m off at 1.6 deg std; tracking: < 0.2;
    # wrong ones on tum_fr1_rpy came at 0.64-0.67: RESULTS.md tracker-reloc-verify)
    reloc_max_rotation_std_deg: float = 0.5
    # a turned prior is first aligned turning only (the camera where the keyframe stood), then
    # fully: a fast rotation that lost the track also rolls, which the image shift misses
    reloc_rotation_first: bool = True
    # the last tracked frame is tried first: a fast turn loses the track where the camera
    # still stands, often far from any keyframe (kf_min_frames apart)
    reloc_last_frame: bool = True
    # a relocalised pose is a candidate until the next frame, tracked from it, has
    # reloc_min_matches inliers and quality good; the candidate frame gets no pose (a wrong
    # relocalisation is a confident wrong pose; RESULTS.md: tracker-reloc-verify)
    reloc_confirm: bool = True
    # both must be reachable from the last pose before the loss: turned no faster than this
    # factor times the camera's turn rate then (at least reloc_min_turn_rate_deg_s), moved by
    # at most reloc_max_move_depths times the depth of the points they match. Seen: kitti00's
    # look-alike places after its turn turned at 3.5-15 deg a frame (2 before) and moved
    # 1-4 depths; tum_fr1_rpy's right relocalisations 0.1-0.3 depths (RESULTS.md:
    # tracker-reloc-verify)
    reloc_turn_rate_factor: float = 1.5
    reloc_min_turn_rate_deg_s: float = 30.0
    reloc_max_move_depths: float = 0.5
    # keyframes tried per lost frame (the newest ones; 0 = all)
    reloc_max_keyframes: int = 0
    # above 0: each lost frame aligns to the last tracked frame and this many of those
    # keyframes, the next lost frame to the next ones, and the frame after the last share
    # tries the ORB step: a lost frame cost 5 tracked ones and set tum_fr1_rpy's p95 at 2.3x
    # the median; shared, 1.5-1.7x, the same frames tracked (RESULTS.md: tracker-reloc-share)
    reloc_keyframes_per_frame: int = 8
    # when direct alignment finds no pose, the lost frame's level-0 corners are matched by ORB
    # descriptor (Hamming distance <= reloc_orb_max_distance) to the map's points, and PnP
    # poses it from all matches, then from those of the reloc_feature_keyframes keyframes
    # hosting most (a view rolled or turned past direct alignment's reach; a 90-degree yaw
    # spin relocalises: tests/test_vo_relocalization.py; vo.feature_relocalization)
    reloc_features: bool = True
    reloc_orb_max_distance: int = 50
    reloc_feature_keyframes: int = 3
    # while relocalising, a new map is initialised on the side (if reinit_when_lost); it is
    # taken once relocalisation has failed this long (seconds) with a usable view: a time, not
    # a frame count (it was 30), so a 10 Hz camera does not wait three times longer; 1.5 s cost
    # tum_fr1_rpy frames, but with seed_skip_unseen 1 s is 6 frames short of its way back into
    # the first map (RESULTS.md: tracker-reloc-verify)
    reinit_after_lost_s: float = 1.0
    # the map a re-initialisation replaced is kept; frames tracked in the new map try to
    # relocalise into it (at most every merge_period_s, in the mapping step, with
    # merge_min_matches inliers), and two tries that agree on the similarity between the maps
    # (turned merge_max_turn_deg, scales within merge_scale_tolerance, the old points placed
    # within merge_max_move_depths scene depths) merge them (vo.map_merge). The scale comes
    # from the new map's points within merge_depth_radius_px of the old ones (at least
    # merge_min_pairs, else all of them). tum_fr1_rpy's old map took 10-18 inliers where its
    # view came back. A try aligns directly to the old keyframes (~10 ms on tum); every
    # merge_features_every-th also matches ORB features (~40 ms more; 0 = never). The period
    # doubles after every merge_backoff_tries tries, up to merge_period_max_s: a place never
    # seen again costs ~1% of a core after 70 s instead of ~8% (tum_fr1_rpy's merges came
    # within 5 s) (RESULTS.md: tracker-map-merge)
    merge_maps: bool = True
    merge_period_s: float = 0.25
    merge_backoff_tries: int = 40
    merge_period_max_s: float = 2.0
    merge_features_every: int = 4
    merge_min_matches: int = 10
    merge_max_turn_deg: float = 3.0
    merge_scale_tolerance: float = 0.25
    merge_max_move_depths: float = 0.2
    merge_depth_radius_px: float = 30.0
    merge_min_pairs: int = 5

    # keyframes and mapping (6.6)
    kf_min_frames: int = 30
    kf_points_ratio: float = 0.9
    lost_points_ratio: float = 0.3
    # also a keyframe (after kf_min_frames) while fewer points than this are seen: a keyframe
    # taken where little was visible must not keep the map from growing (at 320x240 the
    # inliers stay below 50, so a keyframe comes every kf_min_frames, also while hovering)
    kf_min_points: int = 50
    # ... and those two rules only where the view is new: no keyframe within this share of the
    # scene's depth and kf_min_turn_deg (a hover's keyframe every second at 0.3-1 % of the
    # depth replaced the climb's, and the map's scale drifted 8 %: RESULTS.md, tracker-kf-baseline)
    kf_min_baseline: float = 0.05
    kf_min_turn_deg: float = 5.0
    # count the points seen as the frame's inlier matches (as the original SDVL does), else as
    # the grid cells that map points project into (tracking matches one point per cell). The
    # inliers of a keyframe taken in a weak moment (kitti00's turn: 7) held the next keyframe
    # back until kf_min_frames, and the map was lost; map points projecting inside the image
    # (cells or not) stay "visible" while the camera climbs along its optical axis and no
    # keyframe came (hover-down 0.293 m); cells: kitti00 in one map, tum_fr1_rpy 722/723 in
    # one (RESULTS.md: tracker-kf-cells)
    kf_count_inliers: bool = False
    # a point tried and not matched in this many tracked frames in a row no longer counts toward
    # its cell (points on people who walked off still project there); 5 lost kitti00's map
    # from one of six start frames (RESULTS.md: tracker-kf-cell-streak)
    kf_cell_max_unmatched: int = 10
    max_keyframes: int = 30
    covisible_min_shared: int = 10
    # threaded mapping: at most this many tracked frames wait for (or are in) their mapping
    # step; tracking waits for room (the service skips frames meanwhile), so none is dropped
    # from mapping: dropped frames starved the depth filter (RESULTS.md: tracker-slow-mapping)
    mapping_queue_size: int = 4
    # a frame is rated good only while at most this many tracked frames wait for mapping
    # (threaded): tracked against a map that lags, its pose may be far off while the matches
    # look fine
    mapping_lag_good: int = 1

    # local bundle adjustment (6.6.4) on each new keyframe: iterations before and after the
    # chi-square outlier cut; skipped while the mapping thread has frames waiting
    local_ba: bool = False
    ba_first_iterations: int = 5
    ba_second_iterations: int = 10
    # points in the BA need this many keyframe observations besides their host's: with 3 the
    # free keyframes kept too few observations and a BA moved them far; 1 was worse when this
    # was chosen, not on today's survey-down (RESULTS.md: tracker-ba-min-views)
    ba_min_views: int = 2
    # a keyframe is free only with this many observations in the problem (its own and those
    # of the points it hosts, by other keyframes); one the window barely sees is held fixed:
    # tracking placed it from all its matches, a handful of points would place it worse
    ba_min_keyframe_obs: int = 20
    # the BA runs only when the local problem's rms reprojection error is at least this
    # (pixels): below, the keyframes already agree to within the noise and a BA only fits it
    # (RESULTS.md: tracker-local-ba)
    ba_min_rms_px: float = 0.5
    # each free keyframe's pose is held by a prior with the information of all its tracked
    # matches (bundle_adjustment.pose_priors): the few points a BA sees of a keyframe place it
    # worse than tracking did (RESULTS.md: tracker-ba-priors)
    ba_keyframe_prior: bool = True
    # each point's depth filter estimate is a prior with the filter's sigma times this: the
    # filter's sigma is overconfident (its measurements share the host patch and the tracked
    # poses), and held to it a BA moves keyframes to fit the filter (RESULTS.md:
    # tracker-ba-priors)
    ba_depth_prior_inflation: float = 3.0
    # scipy least_squares method, all with the analytic Jacobian: 'trf' or 'dogbox' (sparse;
    # dogbox was not faster overall and ended some problems with other observations
    # dropped), 'lm' (MINPACK, dense: faster only on small problems); or 'gtsam' (vo.ba_gtsam,
    # the optional gtsam package; RESULTS.md: tracker-ba-solvers)
    ba_method: str = "trf"

    # map initialisation (6.6.1)
    init_min_features: int = 50
    init_max_features: int = 300
    init_min_disparity_px: float = 20.0
    init_min_tracked: int = 40
    init_ransac_px: float = 2.0
    init_min_inliers: int = 40
    init_map_depth: float = 1.0
    # the frames the initialiser tracked before the map existed get poses in it once it does
    # (FrameResult.earlier, vo.late_poses): at most this many, the newest (0 = none)
    init_late_poses: int = 60
    # use the 5-point essential matrix instead when the homography explains fewer than this
    # fraction of its inliers (0 = homography only, as in the thesis text)
    init_homography_ratio: float = 0.8

    # points, depth filter and matcher (6.3, 6.5, 6.6.2, 6.6.3)
    seed_a: float = 10.0
    seed_b: float = 10.0
    seed_sigma_ratio: float = 1.0
    convergence_L: float = 0.1
    # 15 keeps a map's points through a fast turn to relocalise into (tum_fr1_rpy in one map)
    # but costs ATE on tum and hover-down (RESULTS.md: tracker-reloc-tum, tracker-reloc-hover)
    seed_max_failures: int = 5
    # a candidate whose depth range projects outside a frame is not searched there (thesis
    # 6.6.3: only visible candidates are), so turning away does not count as failing to find
    # it; it kept tum_fr1_rpy's first map, but lingering candidates cost hover-down ATE
    # (RESULTS.md: tracker-reloc-seeds)
    seed_skip_unseen: bool = False
    # a new candidate no keyframe matched (ground uncovered by people who stood on it in every
    # earlier keyframe) starts at the depth of the plane through the keyframe's converged
    # points, +- this fraction of its inverse depth, when that plane holds seed_plane_min_fit
    # of them to within 2% of their depth (0: such candidates are dropped, as in the thesis;
    # off because at 640x480 it made survey-down and hover-down 2-4x worse, README)
    seed_plane_sigma: float = 0.0
    seed_plane_min_fit: float = 0.9
    # a new candidate no keyframe matched that the keyframes looked towards but had out of
    # view at the scene's depth (ground a take-off climb uncovers at the image's edges) starts
    # from the depth prior instead of being dropped (6.6.2 drops it): the take-off's map then
    # spreads with the view instead of crowding into its centre (RESULTS.md,
    # tracker-unseen-prior)
    seed_unmatched_prior: bool = True
    # ... when they are at least this share of the keyframe's new candidates (a climb: 85-95%;
    # a hand-held camera's few at an edge, tum_fr1_rpy and room-handheld: under 15%)
    seed_prior_min_share: float = 0.25
    epipolar_margin_px: float = 2.0
    # "patch" (affine-warped patches, ZMSSD below zmssd_threshold per pixel) or "orb" (ORB
    # descriptors, 6.5.1, Hamming distance <= orb_max_distance) in every point search
    matcher: str = "patch"
    orb_max_distance: int = 100
    # ORB tracking compares descriptors of FAST corners from this level up (every map point is
    # searched among corners: full resolution has most of them)
    orb_track_min_level: int = 0
    zmssd_threshold: float = 2000.0
    match_max_level: int = 2
    min_inlier_probability: float = 0.1

    # depth (issue 30): given a depth map registered to the image (metres along the optical
    # axis, 0 = none), a map starts on that one frame (metric, no two-view initialisation) and
    # a new keyframe's points start at their measured inverse depth; off: depth is ignored
    depth: bool = True
    # the depth camera's rms error over the squared depth (1/m): stereo and structured-light
    # sensors measure disparity, so sigma_z = z^2 sigma_d / (f b) and the inverse depth's sigma
    # is this constant; 0.004 covers a D435 at 848x480 (0.0036) and a Kinect v1 (0.0016 plus
    # 1/8 px disparity steps)
    depth_noise_per_m2: float = 0.004
    # a corner's depth (median of its 3x3 pixels) is used only where those span at most this
    # fraction of it: corners sit on depth edges, where a pixel off is far off
    depth_edge_rel: float = 0.1

    seed: int = 0

    def __post_init__(self) -> None:
        check_limits(self, "tracker", LIMITS)  # each number's own range (vo/config_limits.py)
        if not 0 <= self.align_min_level <= self.align_max_level < self.pyramid_levels:
            raise InputError("need 0 <= align_min_level <= align_max_level < pyramid_levels")
        if not 0 <= self.track_search_min_level <= self.match_max_level < self.pyramid_levels:
            raise InputError("need 0 <= track_search_min_level <= match_max_level < "
                             "pyramid_levels")
        if self.ba_method not in ("trf", "dogbox", "lm", "gtsam"):
            raise InputError("ba_method must be 'trf', 'dogbox', 'lm' or 'gtsam'")
        if self.ba_method == "gtsam" and importlib.util.find_spec("gtsam") is None:
            raise InputError(GTSAM_MISSING)
        if not 0 <= self.orb_track_min_level <= self.match_max_level:
            raise InputError("need 0 <= orb_track_min_level <= match_max_level")
        if self.matcher not in ("patch", "orb"):
            raise InputError(f"matcher must be 'patch' or 'orb', not {self.matcher!r}")

    @property
    def track_corner_level(self) -> int:
        """Lowest pyramid level whose FAST corners tracking searches."""
        return self.orb_track_min_level if self.matcher == "orb" else self.track_search_min_level

    def ransac_pixels(self, width: int) -> tuple[float, float]:
        """The RANSAC inlier and rescue thresholds in pixels of an image `width` wide."""
        grow = max(1.0, width / self.ransac_reference_width_px)
        return self.ransac_threshold_px * grow, self.ransac_rescue_px * grow

    @classmethod
    def from_dict(cls, d: dict[str, Any], path: str | Path | None = None) -> TrackerConfig:
        """A config from a mapping of parameter names; unknown keys and wrong types are errors."""
        return dataclass_from_table(cls, d, "tracker", path)

    @classmethod
    def from_toml(cls, path: str | Path) -> TrackerConfig:
        """A config from a TOML file (top level, or a [tracker] table)."""
        data = read_toml(path)
        if isinstance(data.get("tracker"), dict):
            data = data["tracker"]
        return cls.from_dict(data, path)

    def to_dict(self) -> dict[str, Any]:
        """The parameters as a plain mapping (for reports and TOML round trips)."""
        return asdict(self)

