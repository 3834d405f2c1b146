"""Every tracker parameter in one place, with the thesis defaults (Perdices 2017, ch. 6-7)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sdvl.errors import InputError
from sdvl.tables import dataclass_from_table, read_toml


@dataclass
class TrackerConfig:
    """Parameters of the SDVL tracker; pixel quantities are at pyramid level 0."""

    # frames (6.2, 6.4)
    pyramid_levels: int = 5
    fast_threshold: int = 10
    # one match per cell in tracking, one new point per empty cell of a keyframe. Tried: 16 px
    # at 320x240 (the 20x15 grid of 640x480). ATE mm patch+rej world seeds 0-2, tracker seeds
    # 0/1/2/3: walkers 13.6/16.2/38.7, 16.6/46.0/30.5, 17.2/26.3/32.6, 13.8/40.1/24.8 (32 px:
    # 22.5/28.0/45.2, 30.8/27.0/38.3, 27.5/21.9/38.6, 27.8/55.6/44.7), walkers-empty 7.0/6.3/
    # 9.8, 6.5/6.3/9.4, 7.8/5.2/9.4, 6.5/6.5/9.9 (11.1/16.3/13.8, 11.3/11.2/11.6, 12.0/10.8/
    # 14.4, 11.6/15.8/13.4); hold tilt rms 0.28 deg (0.41), empty 0.07 (0.13); mostly from the
    # mapping grid (16 px there only: walkers tracker seeds 0/1 25.8/19.3/27.2, 32.3/18.1/27.5;
    # in tracking only 52.1/27.3/40.3, 54.3/24.6/43.6); 24 px no better (34.3/24.4/42.6,
    # 29.3/26.5/47.2). Not taken: on the sliding board of test_vo_outlier_rejection (320x240,
    # tracker seeds 0-2) calm went 3.9/3.7/3.9 -> 1.6/1.6/1.5 mm but busy with rejection
    # 4.4/4.0/4.3 -> 4.2/5.2/4.1, worse than without it (3.2/3.5/3.5): rejected points leaving
    # the map cost it (point_max_rejected 1000: 2.4/2.5/2.6); tracking 1.5x slower at 320x240.
    # 16 px with point_max_rejected 10: board busy 3.0/3.0/2.8, calm 1.7/1.6/1.7 (10 with 32 px
    # cells: busy 5.9/6.2/5.3); walkers 16.8/20.3/29.8, 16.5/16.2/25.1, 16.8/18.3/24.3,
    # 20.7/16.4/18.6 (mean 20.0, 32 px 34.0), empty 8.7/7.8/12.0, 8.5/8.3/13.2, 8.6/7.7/11.2,
    # 8.2/8.1/12.4 (9.6, 32 px 12.8); hold tilt rms 0.27 deg, empty 0.075
    grid_cell: int = 32

    # sparse image alignment (6.7.1)
    align_max_level: int = 4
    align_min_level: int = 2
    align_iterations: int = 30
    # Tukey-weighted intensity residuals (vo.sparse_align), else plain least squares (6.10).
    # ATE m robust (plain): survey-long 320x240 world seeds 0-3 .43/.48/.50/.63
    # (.60/.39/12.0/.44; seed 2 with local BA gate 0.5 .43 (24.4), gate 0 .63 (31.5));
    # survey-down world seeds 0-4 tracker seed 0 .11/.07/.48/.09/.07 (.28/.17/.35/.08/1.17),
    # tracker seed 1 .12/.16/.14/.06/.11 (.12/.38/.05/.09/.42); kitti00_first200 tracker
    # seeds 0-19 mean .77 (.82), better on 12 of 20
    align_robust: bool = True

    # feature alignment and pose refinement (6.7.2, 6.7.3)
    max_matches: int = 200
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

    # outlier rejection (6.8): RANSAC over 5-point subsets of the matches, inliers within
    # ransac_threshold_px (image pixels), hypotheses for ransac_probability at most
    # ransac_max_hypotheses; then outliers within ransac_rescue_px of the inlier pose rejoin
    outlier_rejection: bool = False
    ransac_threshold_px: float = 2.0
    ransac_rescue_px: float = 4.0
    ransac_probability: float = 0.99
    ransac_max_hypotheses: int = 100
    # with outlier rejection, a point matched but rejected this many tracked frames in a row
    # leaves the map (a person who stood while mapped and walked off; its many finds kept it
    # first in its grid cell, where it kept closing the cell to the ground points). 10 at
    # 640x480 world seed 0, patch+rej tracker seeds 0/1, ATE mm: hover-down 11.8/10.1 (now
    # 11.2/10.1), survey-down 52/35 (117/56); with 32 px cells at 320x240 it lost on the sliding
    # board, with 16 px it won there and on walkers (grid_cell)
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
    # (zero-mean residual over patch energy: 0 perfect, ~1 blank image, ~2 unrelated texture)
    reloc_max_residual_ratio: float = 0.5
    # pyramid level at which the image shift to a keyframe is found (phase correlation)
    reloc_shift_level: int = 2
    # a relocalised pose must be this well determined (largest rotation std of its covariance,
    # degrees): matches crowded into the sliver of view shared with a keyframe leave tilt and
    # sideways position confused (seen: 14 deg and 2.7 m off at 1.6 deg std; tracking: < 0.2)
    reloc_max_rotation_std_deg: float = 0.5
    # keyframes tried per lost frame (the newest ones; 0 = all)
    reloc_max_keyframes: int = 0
    # while relocalising, a new map is initialised on the side (if reinit_when_lost); it is
    # taken once relocalisation has failed this many frames with a usable view
    reinit_after_lost_frames: int = 30

    # keyframes and mapping (6.6)
    kf_min_frames: int = 30
    kf_points_ratio: float = 0.9
    lost_points_ratio: float = 0.3
    # also a keyframe (after kf_min_frames) while fewer points than this are seen. At 320x240
    # the inliers stay below 50 (walkers, walkers-empty: 17-49), so a keyframe comes every
    # kf_min_frames, also while hovering (baselines 0.01-0.2 m at 5 m). Withholding keyframes
    # closer than 0.05 x median depth to every keyframe (unless < 20 inliers) measured, ATE mm
    # patch+rej world seeds 0-2, tracker seed 0 / 1: walkers 19.0/34.0/34.6, 19.1/36.9/62.1
    # (now 22.5/28.0/45.2, 30.8/27.0/38.3), walkers-empty 9.4/18.7/13.8, 9.4/11.4/11.6 (now
    # 11.1/16.3/13.8, 11.3/11.2/11.6); 0.1 without the floor lost walkers seed 2. The hovering
    # walkers' error is sideways position traded for tilt (about 5.3 m per rad, the height)
    kf_min_points: int = 50
    # count the points seen as the frame's inlier matches (as the original SDVL does), else as
    # the map points projecting inside the image: those stay "visible" while the camera climbs
    # along its optical axis, but they crowd into fewer grid cells (one match per cell), so the
    # matches fall and no keyframe comes
    kf_count_inliers: bool = True
    max_keyframes: int = 30
    covisible_min_shared: int = 10
    # threaded mapping: at most this many tracked frames wait for (or are in) their mapping
    # step; tracking waits for room (the service skips frames meanwhile), so none is dropped
    # from mapping. Dropped frames starved the depth filter (emulated mapping at half the
    # frame rate, sdvl track --mapping-period 2, survey-down tracker seeds 0-2: 9.3/8.6/9.4 m,
    # ~960 frames rated good; mapping at the frame rate but keyframe steps 4 periods long:
    # 53-59 frames dropped, 7.1/7.8/8.0 m, now 2.7/0.13/7.4 m with 46-52 frames skipped).
    # Waiting does not make a mapper at half rate accurate: 7.6/7.3/8.5 m
    # (size 2: 2.3/2.1/0.19 m, the map only one frame behind; tracking every 2nd frame
    # sequentially gives 0.21 m, every 3rd 3.9 m on seed 0); what it buys is mapping_lag_good
    mapping_queue_size: int = 4
    # a frame is rated good only while at most this many tracked frames wait for mapping
    # (threaded): tracked against a map that lags, its pose may be far off while matches look
    # fine. Emulated mapping at 1/2 and 1/3 of the frame rate, survey-down seeds 0-2: frames
    # rated good with an error over 3x the sequential ATE 991/952/967 and 904/904/904 before,
    # 6/6/7 and 12/12/12 with this (size 2 never lags by 2: 518/522/29 and 323/306/339)
    mapping_lag_good: int = 1

    # local bundle adjustment (6.6.4) on each new keyframe: iterations before and after the
    # chi-square outlier cut; skipped while the mapping thread has frames waiting
    local_ba: bool = False
    ba_first_iterations: int = 5
    ba_second_iterations: int = 10
    # points in the BA need this many keyframe observations besides their host's; with 3
    # (before) the free keyframes kept 0-12 of their ~50 observations (kitti00, survey-down)
    # and one BA moved them by 0.3-1.1 m. 1 is worse again on survey-down (0.51 m, 2: 0.095)
    ba_min_views: int = 2
    # a keyframe is free only with this many observations in the problem (its own and those
    # of the points it hosts, by other keyframes); one the window barely sees is held fixed:
    # tracking placed it from all its matches, a handful of points would place it worse
    ba_min_keyframe_obs: int = 20
    # the BA runs only when the local problem's rms reprojection error is at least this
    # (pixels): below, the keyframes already agree to within the noise. With the robust
    # sparse alignment, ATE m BA off / on (this gate) / gate 0, every run 1 segment and the
    # same frames tracked: kitti00 (kitti_10hz, patch+rej) tracker seeds 0-9
    # .98/1.17/1.61/.76/.44/1.38/.23/.99/.48/.83 (mean .89),
    # .83/1.09/1.41/1.12/1.02/.29/.35/1.17/.40/.93 (.86, better on 5 of 10),
    # .84/.95/1.19/1.12/1.02/.29/.82/1.17/.36/.97 (.88); survey-long 320x240 world seeds 0-3
    # .43/.48/.50/.63 (.51), .47/.57/.43/.52 (.50, better on 2 of 4); survey-down 640x480
    # world seeds 0-4 .11/.07/.48/.09/.07 (.16), .07/.20/.08/.06/.07 (.10, better on 3, same
    # on 1). No clear gain: on kitti00 21 of 28 BAs pass the gate, free 2-3 keyframes (7
    # fixed, ~40 points), move them by a median 0.4-0.9 mm and leave the window's keyframe
    # error against the truth (0.08-0.20 m) where it was (better in half the BAs); held by
    # the pose priors they only nudge depths (median 0.2%), which reshuffles the tracker like
    # any small change. Without the pose priors kitti00 mean 3.75 m (seed 3 lost, 29 m).
    ba_min_rms_px: float = 0.5
    # each free keyframe's pose is held by a prior with the information of all its tracked
    # matches (bundle_adjustment.pose_priors). ATE BA on (off), tracker seeds 0/1/2: kitti00
    # without 3.01/1.63/0.67, with 0.62/1.00/0.27 (0.26/0.83/0.72); survey-down with
    # ba_min_rms_px 0 without 0.23/0.25/0.23, with 0.11/0.10/0.13 (0.054/0.083/0.053);
    # room-handheld without 0.0054/0.0116/0.0190, with 0.0046/0.0103/0.0059 (0.0049/0.0043/
    # 0.0046): less harm, still not better than no BA on the synthetic flights
    ba_keyframe_prior: bool = True
    # each point's depth filter estimate is a prior with the filter's sigma times this. The
    # filter's sigma is overconfident (its measurements share the host patch and the tracked
    # poses), and held to it the BA moved keyframes to fit the filter's depths. ATE BA on,
    # tracker seeds 0-5, 1 -> 3: kitti00 .62/1.00/.27/1.30/1.46/.47 -> .33/1.04/.26/.35/.54/
    # .24 m (BA off .27/.83/.72/.81/1.24/.31); room-handheld seeds 0-2 .0046/.0103/.0059 ->
    # .0042/.0043/.0122 (off .0049/.0043/.0046); survey-down with ba_min_rms_px 0, seeds 0-4
    # .108/.102/.134/.066/.065 -> .051/.043/.044/.041/.057 (off .054/.083/.053/.051/.119).
    # 10: kitti00 .30/1.35/.79
    ba_depth_prior_inflation: float = 3.0
    # scipy least_squares method, all with the analytic Jacobian: 'trf' or 'dogbox' (sparse;
    # dogbox 0.4-1.1x trf's time on kitti00/survey-down/room-handheld problems and on 3 of 28
    # it ended with other observations dropped), 'lm' (MINPACK, dense: 2-4x faster below ~50
    # unknowns, 8x slower at 230)
    ba_method: str = "trf"

    # map initialisation (6.6.1)
    init_min_features: int = 50
    init_max_features: int = 300
    init_min_disparity_px: float = 20.0
    init_min_tracked: int = 40
    init_ransac_px: float = 2.0
    init_min_inliers: int = 40
    init_map_depth: float = 1.0
    # use the 5-point essential matrix instead when the homography explains fewer than this
    # fraction of its inliers (0 = homography only, as in the thesis text)
    init_homography_ratio: float = 0.8

    # points, depth filter and matcher (6.3, 6.5, 6.6.2, 6.6.3)
    seed_a: float = 10.0
    seed_b: float = 10.0
    seed_sigma_ratio: float = 1.0
    convergence_L: float = 0.1
    seed_max_failures: int = 5
    # a new candidate no keyframe matched (ground uncovered by people who stood on it in every
    # earlier keyframe) starts at the depth of the plane through the keyframe's converged
    # points, +- this fraction of its inverse depth, when that plane holds seed_plane_min_fit
    # of them to within 2% of their depth (0: such candidates are dropped, as in the thesis;
    # off because at 640x480 it made survey-down and hover-down 2-4x worse, README)
    seed_plane_sigma: float = 0.0
    seed_plane_min_fit: float = 0.9
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

    seed: int = 0

    def __post_init__(self) -> None:
        if not 1 <= self.pyramid_levels <= 8:
            raise InputError("pyramid_levels must be between 1 and 8")
        if not 0 <= self.align_min_level <= self.align_max_level < self.pyramid_levels:
            raise InputError("need 0 <= align_min_level <= align_max_level < pyramid_levels")
        if not 0 <= self.track_search_min_level <= self.match_max_level < self.pyramid_levels:
            raise InputError("need 0 <= track_search_min_level <= match_max_level < "
                             "pyramid_levels")
        if self.ba_method not in ("trf", "dogbox", "lm"):
            raise InputError("ba_method must be 'trf', 'dogbox' or 'lm'")
        if not 0 <= self.orb_track_min_level <= self.match_max_level:
            raise InputError("need 0 <= orb_track_min_level <= match_max_level")
        if self.matcher not in ("patch", "orb"):
            raise InputError(f"matcher must be 'patch' or 'orb', not {self.matcher!r}")
        if not 0 <= self.orb_max_distance <= 256:
            raise InputError("orb_max_distance must be between 0 and 256")
        if self.grid_cell < 8 or self.max_matches < 6 or self.max_keyframes < 3:
            raise InputError("grid_cell >= 8, max_matches >= 6 and max_keyframes >= 3 required")

    @property
    def track_corner_level(self) -> int:
        """Lowest pyramid level whose FAST corners tracking searches."""
        return self.orb_track_min_level if self.matcher == "orb" else self.track_search_min_level

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

