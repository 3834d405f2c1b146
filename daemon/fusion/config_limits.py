"""The range of every number in FusionConfig (config.py), checked by FusionConfig.check.

Wide enough for any vehicle and any tuning, narrow enough that a typo (1e300, a value in the
wrong unit) is an error naming the key, not a variance that overflows the filter, a filter that
never publishes, or a history that grows without bound (issue 28).
"""

from __future__ import annotations

from sdvl.tables import interval

LEVER = interval(-10, 10, why="metres from the autopilot's IMU")
STD_M = interval(above=0, high=1000)  # a standard deviation in metres
DEG = interval(above=0, high=180)
DRIFT = interval(0, 10)  # a random walk's growth, per sqrt(metre or second)
LN_SCALE_STD = interval(above=0, high=10, why="of ln(scale): 10 is 22,000x either way")
INFLATION = interval(1, 1e6, why="a variance factor")
CHI2 = interval(above=0, high=1e6)
SECONDS = interval(above=0, high=3600)

LIMITS = {
    "camera_x_m": LEVER,
    "camera_y_m": LEVER,
    "camera_z_m": LEVER,
    "publish_max_std_m": STD_M,
    "scale_std_max": interval(above=0, high=1),
    "heading_std_max_deg": DEG,
    "min_aligned_s": interval(0, 3600),
    "progress_interval_s": SECONDS,
    "rest_velocity_std": interval(above=0, high=10),
    "rest_window_s": interval(above=0, high=60),
    "rest_accel_tol": interval(above=0, high=10),
    "rest_gyro_tol": interval(above=0, high=10),
    "flight_state_timeout_s": interval(above=0, high=600),
    "scale_prior_std": LN_SCALE_STD,
    "initial_scale": interval(1e-6, 1e6, why="metres per VO unit"),
    "map_depth_units": interval(1e-6, 1e6),
    "range_scale_prior_std": LN_SCALE_STD,
    "start_velocity_std": interval(above=0, high=100),
    "coarse_scale_std": LN_SCALE_STD,
    "coarse_inflation": INFLATION,
    "nav_scale_std": LN_SCALE_STD,
    "vo_position_std_m": interval(above=0, high=100),
    "vo_rotation_std_deg": DEG,
    "vo_covariance_factor": interval(above=0, high=1e6),
    "vo_tilt_error_std_deg": interval(above=0, high=90),
    "vo_error_time_s": SECONDS,
    "vo_drift_m_per_sqrt_m": DRIFT,
    "vo_drift_climb_m_per_sqrt_m": DRIFT,
    "vo_drift_m_per_sqrt_s": DRIFT,
    "reanchor_distance_m": interval(above=0, high=10_000),
    "inflate_insufficient": INFLATION,
    "inflate_bad": INFLATION,
    "attitude_std_deg": DEG,
    "heading_std_deg": DEG,
    "heading_bias_std_deg": interval(0, 180),
    "attitude_timeout_s": interval(above=0, high=10),
    "alignment_walk_deg_per_sqrt_m": interval(0, 180),
    "scale_walk_per_sqrt_m": DRIFT,
    "scale_walk_climb_per_sqrt_m": DRIFT,
    "accel_noise": interval(above=0, high=100),
    "accel_bias_std": interval(above=0, high=100),
    "accel_bias_walk": interval(0, 100),
    "imu_timeout_s": interval(above=0, high=10),
    "motion_accel_std": interval(above=0, high=1000),
    "range_std_m": interval(above=0, high=100),
    "range_std_fraction": interval(0, 1),
    "range_max_tilt_deg": interval(above=0, below=90),
    "ground_walk_m_per_sqrt_m": interval(0, 100),
    "terrain_relief_m": STD_M,
    "terrain_correlation_m": interval(above=0, high=100_000),
    "scene_height_std_fraction": interval(above=0, high=1),
    "baro_std_m": STD_M,
    "baro_walk_m_per_sqrt_s": interval(0, 100),
    "baro_ground_effect_height_m": interval(0, 100),
    "climb_scale_min_m": interval(above=0, high=1000),
    "gate_chi2_1dof": CHI2,
    "gate_chi2_2dof": CHI2,
    "gate_chi2_3dof": CHI2,
    "gate_chi2_6dof": CHI2,
    "reset_after_rejections": interval(1, 1_000_000),
    # the filter keeps a snapshot per frame for this long (late messages replay from one)
    "history_s": interval(above=0, high=10, why="snapshots kept in memory"),
    "clock_offset_window_s": interval(above=0, high=600, why="delays kept in memory"),
    "time_offset_std_s": interval(above=0, high=1),
    "time_offset_walk_s_per_sqrt_s": interval(0, 1),
    "quality_good_std_m": STD_M,
    "rate_std_rad_s": interval(above=0, high=100),
}
