"""Settings of the fusion filter: noise models, thresholds for publishing, sensor limits.

All fields are plain numbers or flags, so the service can read them from a `[fusion]` TOML table
with the same validation as its other sections. Standard deviations are in SI units (m, m/s,
m/s^2, rad); `*_deg` fields are degrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from daemon.fusion.config_limits import LIMITS
from sdvl.tables import check_limits


@dataclass(frozen=True)
class FusionConfig:
    """Defaults suit a small multirotor with a downward camera and an ArduPilot/PX4 autopilot."""

    # false: the service uses the pass-through estimator (mounting.scale, no autopilot sensors)
    enabled: bool = True
    # camera position in the body frame (FRD, metres): the lever arm between camera and IMU
    camera_x_m: float = 0.0
    camera_y_m: float = 0.0
    camera_z_m: float = 0.0
    # estimates go out from the autopilot's first ATTITUDE on, with the filter's covariance
    # (the autopilot's VisOdom pre-arm check needs them before take-off); none while the
    # horizontal position std is above this (the filter no longer knows where the vehicle is)
    publish_max_std_m: float = 10.0
    # the map counts as aligned (STATUSTEXT, and the scale fits stop) once scale and heading
    # standard deviations have been below these for min_aligned_s
    scale_std_max: float = 0.03  # relative (0.03 = 3 %)
    heading_std_max_deg: float = 2.0
    min_aligned_s: float = 0.5
    progress_interval_s: float = 2.0
    # standing still (rest.py): zero velocity fused with this std while the autopilot says it
    # is landed, or it is disarmed and its IMU has been quiet for rest_window_s (specific force
    # within rest_accel_tol of g, rates below rest_gyro_tol); flight states older than
    # flight_state_timeout_s are not used
    rest_velocity_std: float = 0.01  # m/s
    rest_window_s: float = 0.5
    rest_accel_tol: float = 0.3  # m/s^2
    rest_gyro_tol: float = 0.03  # rad/s
    flight_state_timeout_s: float = 3.0
    # priors of a new map segment
    scale_prior_std: float = 2.0  # of ln(scale): 2.0 lets the scale be 7x off either way
    initial_scale: float = 1.0  # metres per VO unit guessed for the first segment
    # the tracker scales a new map so that its median scene depth is this many units (vo's
    # init_map_depth): a downward rangefinder's distance then gives the scale to within
    # range_scale_prior_std (ln), a start the EKF's linearisation does not run away from
    map_depth_units: float = 1.0
    range_scale_prior_std: float = 0.3
    # speed std when the filter starts on a vehicle that may be moving (a restart in flight)
    start_velocity_std: float = 3.0  # m/s
    # while the std of ln(scale) is above coarse_scale_std the tracker's horizontal noise is
    # inflated by coarse_inflation (variance factor), so updates linearised around a scale still
    # far off do not shrink the covariance before the estimate gets there
    coarse_scale_std: float = 0.2
    coarse_inflation: float = 10.0
    # while the std of ln(scale) is above nav_scale_std the tracker's positions update only the
    # map's scale, anchor and tilt, not the vehicle's position, velocity or IMU bias: an update
    # linearised around a scale 1.6x off or more threw the estimate 33 m in 1.5 s, then sure of
    # it (RESULTS.md: fly-640); the IMU, barometer and rangefinder carry the vehicle meanwhile
    nav_scale_std: float = 0.5
    # tracker pose: floor of the position noise (metres) and inflation per tracking quality
    vo_position_std_m: float = 0.005
    vo_rotation_std_deg: float = 0.2
    # variance factor on the tracker's position covariance (it matches its frame-to-frame noise;
    # the slow tilt error and drift it leaves out are modelled below)
    vo_covariance_factor: float = 1.0
    # its slowly wandering tilt error and the position error that goes with it (state.py): std
    # and correlation time, as the tracker shows on the synthetic downward flights
    vo_tilt_error_std_deg: float = 0.5
    vo_error_time_s: float = 1.0
    # VO position random walk per sqrt(metre flown horizontally), and sideways per sqrt(metre
    # climbed or descended (a climb re-triangulates the scene at new depths); set by the
    # position NEES of the lockstep replays (RESULTS.md fusion-*); real imagery may drift more:
    # raise them when a flight's NEES or the autopilot's innovations say so
    vo_drift_m_per_sqrt_m: float = 0.002
    vo_drift_climb_m_per_sqrt_m: float = 0.03
    vo_drift_m_per_sqrt_s: float = 0.0  # VO position random walk per sqrt(second), also at rest
    reanchor_distance_m: float = 5.0  # fuse the map relative to a pose at most this far back
    inflate_insufficient: float = 4.0  # variance factor
    inflate_bad: float = 25.0
    # autopilot attitude (ATTITUDE): roll/pitch and compass heading noise
    attitude_std_deg: float = 0.5
    heading_std_deg: float = 3.0
    # compass bias: it turns the local frame (north is the compass's) against true north, so it
    # is in the alignment gate's heading std, not in the covariance sent (the autopilot fuses
    # our poses in its own heading frame)
    heading_bias_std_deg: float = 1.0
    attitude_timeout_s: float = 0.5
    # VO rotation drift against the autopilot's, per sqrt(metre flown) like the scale's
    alignment_walk_deg_per_sqrt_m: float = 0.1
    # ln(scale) random walk per sqrt(metre flown): the map's scale drifts as it grows over new
    # ground, not while the camera hovers over the same points
    scale_walk_per_sqrt_m: float = 0.002
    # per sqrt(metre climbed or descended): the scene depth changes and new points are
    # triangulated at it, so a climb moves the scale more than level flight does
    scale_walk_climb_per_sqrt_m: float = 0.02
    # IMU (HIGHRES_IMU / SCALED_IMU / RAW_IMU): accelerometer noise and bias
    use_imu: bool = True
    # m/s^2/sqrt(Hz) white noise, the attitude's error times g included: a floor; in flight
    # the stream's own noise (motor vibration folded into its samples) is measured and used
    # when larger (imu_noise.py)
    accel_noise: float = 0.02
    accel_bias_std: float = 0.2  # m/s^2 initial
    # m/s^2 per sqrt(s): the 50 Hz stream folds the motors' vibration into offsets that wander
    # with their speeds (simulated: 0.1-0.15 m/s^2 within 2-10 s; RESULTS.md, issue 27)
    accel_bias_walk: float = 0.1
    imu_timeout_s: float = 0.1
    # without IMU: constant velocity with this white acceleration noise (m/s^2/sqrt(Hz)); the
    # tracker corrects manoeuvres at frame rate, a small value keeps its map from wandering
    motion_accel_std: float = 0.5
    # downward rangefinder (DISTANCE_SENSOR, orientation PITCH_270)
    use_rangefinder: bool = True
    range_std_m: float = 0.05
    range_std_fraction: float = 0.01
    range_max_tilt_deg: float = 30.0
    ground_walk_m_per_sqrt_m: float = 0.05  # terrain height change per sqrt(metre flown)
    # the map's own height above the ground (median depth of the matched points below the
    # camera, scene.py) against the rangefinder's: the scale in level flight without an IMU.
    # The ground the map sees differs from the one under the rangefinder by the spread of the
    # matched points' heights, at least terrain_relief_m (std), a new sample every
    # terrain_correlation_m flown; the median's own noise is scene_height_std_fraction of the
    # height
    use_scene_height: bool = True
    terrain_relief_m: float = 0.05
    terrain_correlation_m: float = 10.0
    scene_height_std_fraction: float = 0.005
    # barometer (SCALED_PRESSURE, HIGHRES_IMU pressure or PX4 ALTITUDE)
    use_baro: bool = True
    baro_std_m: float = 0.3
    baro_walk_m_per_sqrt_s: float = 0.02
    # below this height above where the vehicle stood, the barometer is not fused: its rotors'
    # ground effect moves it by metres (ArduPilot PR #32472: -5 to -11 m at spool-up on flown
    # airframes; SITL's SIM_BARO_GEFF_M decays to nothing at 2 m), which no noise figure
    # covers and the climb would take for the scale; the IMU and the map carry the height
    # there, and the barometer's offset is referenced again above it (0: fused everywhere)
    baro_ground_effect_height_m: float = 2.0
    # while the filter does not know the scale (no rangefinder, no IMU fix yet), it is taken
    # from a least-squares fit of the tracker's height against the barometer's altitude once
    # the barometer has seen this much climb above the ground effect (climb_scale.py), not
    # from the wide prior's linearised fixes. A 3 m take-off leaves about 1 m above it: at
    # 1.0 the fit came as LOITER began, and moving the vehicle to where the map saw it go
    # then moved it in the hold (0.33-0.35 m; the fit's std says how short the climb was)
    climb_scale_min_m: float = 0.5
    # outlier rejection: chi-square gate per measurement (99.9 % for 1, 2, 3, 6 dof: 10.8, 13.8,
    # 16.3, 22.5)
    gate_chi2_1dof: float = 10.8
    gate_chi2_2dof: float = 13.8
    gate_chi2_3dof: float = 16.3
    gate_chi2_6dof: float = 22.5  # tracker position and attitude together
    reset_after_rejections: int = 10  # in a row: re-reference range/baro, re-align the map
    # timing
    history_s: float = 1.0  # late messages up to this old are fused by replaying the filter
    clock_offset_window_s: float = 10.0
    # the autopilot's stamps mapped to our clock (clock.py) against the camera's: off by the
    # link's least latency (the offset is estimated from arrivals), the camera's own delay and
    # the autopilot's sampling; the filter estimates it (state.py TIME_OFFSET) from this std,
    # wandering as the clock map's estimate does
    time_offset_std_s: float = 0.02
    time_offset_walk_s_per_sqrt_s: float = 0.0005
    # output
    quality_good_std_m: float = 0.05  # position std that earns quality 100
    rate_std_rad_s: float = 0.05

    def check(self, path: Path | None = None) -> None:
        """InputError naming the first setting out of its range (config_limits.py)."""
        check_limits(self, "fusion", LIMITS, path)
