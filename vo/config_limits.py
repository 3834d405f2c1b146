"""The range of every number in TrackerConfig (vo/config.py), checked when a config is built.

Wide enough for any camera and any experiment, narrow enough that a typo (1e300, a minus sign,
a value in the wrong unit) is an error naming the key instead of an overflow, a traceback or a
map that grows without bound (issue 28). Relations between values are checked in TrackerConfig.
"""

from __future__ import annotations

from sdvl.tables import interval

LEVEL = interval(0, 7)  # a pyramid level (at most 8 levels)
PIXELS = interval(above=0, high=1000)  # a distance in image pixels
SHARE = interval(0, 1)
ITERATIONS = interval(1, 1000)
COUNT = interval(0, 100_000)  # points, matches, frames, corners
SOME = interval(1, 100_000)  # a count that must be at least one

LIMITS = {
    "pyramid_levels": interval(1, 8),
    "fast_threshold": interval(1, 255, why="an intensity difference of 8-bit pixels"),
    "grid_cell": interval(8, 1024),
    "align_max_level": LEVEL,
    "align_min_level": LEVEL,
    "align_iterations": ITERATIONS,
    "max_matches": interval(6, 100_000),
    "crowded_min_matches": interval(0, 100_000),
    "align2d_iterations": ITERATIONS,
    "candidate_min_updates": COUNT,
    "point_max_missed": SOME,
    "track_search_min_level": LEVEL,
    "pose_iterations": ITERATIONS,
    "reprojection_inlier_px": PIXELS,
    "rotation_prior_deg": interval(0, 180, why="0: the rotation prior is off"),
    "rotation_prior_gate_deg": interval(above=0, high=180),
    "ransac_threshold_px": PIXELS,
    "ransac_rescue_px": PIXELS,
    "ransac_probability": interval(above=0, below=1),
    "ransac_max_hypotheses": SOME,
    "point_max_rejected": SOME,
    "quality_min_ratio": SHARE,
    "quality_min_matches": COUNT,
    "lost_after_bad": SOME,
    "reloc_min_matches": SOME,
    "reloc_max_residual_ratio": interval(above=0, high=10),
    "reloc_shift_level": LEVEL,
    "reloc_max_rotation_std_deg": interval(above=0, high=180),
    "reloc_turn_rate_factor": interval(above=0, high=1000),
    "reloc_min_turn_rate_deg_s": interval(0, 100_000),
    "reloc_max_move_depths": interval(above=0, high=1000),
    "reloc_max_keyframes": interval(0, 1000, why="0: all"),
    "ransac_reference_width_px": interval(1, 100_000),
    "reloc_orb_max_distance": interval(0, 256, why="bits of a 256-bit descriptor"),
    "reloc_feature_keyframes": SOME,
    "reinit_after_lost_s": interval(0, 3600),
    "kf_min_frames": COUNT,
    "kf_points_ratio": SHARE,
    "lost_points_ratio": SHARE,
    "kf_min_points": COUNT,
    "kf_cell_max_unmatched": SOME,
    # each keyframe keeps its image pyramid and corners (~1 MB at 640x480): the map's memory
    "max_keyframes": interval(3, 1000, why="the map's memory grows with it"),
    "covisible_min_shared": SOME,
    "mapping_queue_size": interval(1, 100, why="frames held in memory while they wait"),
    "mapping_lag_good": interval(0, 100),
    "ba_first_iterations": interval(0, 1000),
    "ba_second_iterations": interval(0, 1000),
    "ba_min_views": interval(0, 1000),
    "ba_min_keyframe_obs": COUNT,
    "ba_min_rms_px": interval(0, 1000),
    "ba_depth_prior_inflation": interval(above=0, high=1e6),
    "init_min_features": interval(5, 100_000),
    "init_max_features": interval(5, 100_000),
    "init_min_disparity_px": interval(0, 10_000),
    "init_min_tracked": interval(5, 100_000),
    "init_ransac_px": PIXELS,
    "init_min_inliers": interval(5, 100_000),
    "init_map_depth": interval(above=0, high=1e6),
    "init_late_poses": interval(0, 10_000),
    "init_homography_ratio": SHARE,
    "seed_a": interval(above=0, high=1e6),
    "seed_b": interval(above=0, high=1e6),
    "seed_sigma_ratio": interval(above=0, high=1e6),
    "convergence_L": interval(above=0, high=1000),
    "seed_max_failures": SOME,
    "seed_plane_sigma": interval(0, 10, why="0: candidates no keyframe matched are dropped"),
    "seed_plane_min_fit": SHARE,
    "seed_prior_min_share": SHARE,
    "epipolar_margin_px": interval(0, 1000),
    "orb_max_distance": interval(0, 256, why="Hamming distance of 256-bit descriptors"),
    "orb_track_min_level": LEVEL,
    "zmssd_threshold": interval(above=0, high=1e6),
    "match_max_level": LEVEL,
    "min_inlier_probability": SHARE,
    "depth_noise_per_m2": interval(above=0, high=1),
    "depth_edge_rel": interval(0, 10),
    "seed": interval(0, 2**32 - 1, why="numpy's seeds are non-negative 32-bit"),
}
