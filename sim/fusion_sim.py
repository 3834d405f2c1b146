"""A simulated flight for the fusion filter (its tests and `sdvl fusion-sim`): ground truth,
the autopilot's sensor messages as pymavlink messages with their arrival times, and tracker
results made from the truth (unknown scale, arbitrary world frame, noise, drift in position,
scale and rotation, quality drops, new map segments).

The flight: take-off from the ground to 8 m, then a stop-and-go lawnmower survey, minimum-jerk
between waypoints; attitude follows the acceleration like a multirotor's.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from daemon.config import MountingConfig
from daemon.fusion.config import FusionConfig
from daemon.fusion.scene import SceneResult
from daemon.mounting import body_from_camera
from sim.replay.fusion_scores import turned_about_down
from vo.result import FrameResult, Quality

GRAVITY = np.array([0.0, 0.0, 9.80665])
DT = 0.005  # truth at 200 Hz
BOOT_OFFSET = 123.456  # our clock minus the autopilot's boot clock
CAMERA_HEIGHT = 0.15  # camera above ground when landed
CHI2_3DOF_3SIGMA = 14.16  # chi-square, 3 dof, with the tail of a 3-sigma Gaussian (0.27 %)


@dataclass
class Truth:
    """Body position, velocity (NED), attitude R_N_b and specific force (body) at 200 Hz."""

    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    R: np.ndarray
    f: np.ndarray

    def at(self, t: float) -> int:
        return int(np.clip(round((t - self.t[0]) / DT), 0, len(self.t) - 1))

    def distance(self, t0: float, t1: float) -> float:
        i, j = self.at(t0), self.at(t1)
        return float(np.sum(np.linalg.norm(np.diff(self.p[i:j + 1], axis=0), axis=1)))


def _min_jerk(p0: np.ndarray, p1: np.ndarray, n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n, endpoint=False)[:, None]
    return p0 + (p1 - p0) * (10 * s**3 - 15 * s**4 + 6 * s**5)


def survey_flight(climb_m: float = 8.0, leg_m: float = 30.0, legs: int = 4,
                  yaw_deg: float = 35.0, yaw_swing_deg: float = 11.5,
                  yaw_period_s: float = 40.0) -> Truth:
    """Take-off (4 s climb after 1 s on the ground), lawnmower legs at 3 m/s, hover 1 s."""
    waypoints = [np.zeros(3), np.zeros(3), np.array([0.0, 0.0, -climb_m])]
    durations = [1.0, 4.0]
    for k in range(legs):
        x = leg_m if k % 2 == 0 else 0.0
        last = waypoints[-1]
        waypoints += [np.array([x, last[1], -climb_m]), np.array([x, last[1] + 8.0, -climb_m])]
        durations += [leg_m / 2.0, 4.0]
    chunks = [_min_jerk(a, b, round(d / DT))
              for a, b, d in zip(waypoints[:-1], waypoints[1:], durations, strict=True)]
    p = np.concatenate([*chunks, np.repeat(waypoints[-1][None], int(1.0 / DT), 0)])
    t = np.arange(len(p)) * DT
    v = np.gradient(p, DT, axis=0)
    a = np.gradient(v, DT, axis=0)
    yaw = np.radians(yaw_deg + yaw_swing_deg * np.sin(2 * np.pi * t / yaw_period_s))
    R = _attitudes(a, yaw)
    f = np.einsum("nji,nj->ni", R, a - GRAVITY)
    return Truth(t, p, v, R, f)


def _attitudes(accel: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """R_N_b whose -z axis carries the thrust for `accel`, with heading `yaw` (N rows)."""
    z = GRAVITY - accel
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    heading = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=1)
    y = np.cross(z, heading)
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    return np.stack([np.cross(y, z), y, z], axis=2)


@dataclass
class SensorOptions:
    """Which autopilot sensors exist and how noisy they are."""

    imu: str | None = "SCALED_IMU"
    imu_hz: float = 50.0
    accel_noise: float = 0.05
    accel_bias: tuple = (0.05, -0.04, 0.08)
    # what the 50 Hz stream folds the motors' vibration into: per axis a seeded slow wander of
    # this amplitude (m/s^2) and 0.05-0.5 Hz (0: none; sim/autopilot flies 0.1-0.15)
    accel_wander: float = 0.0
    attitude_hz: float = 20.0
    tilt_noise_deg: float = 0.3
    heading_noise_deg: float = 1.0
    heading_bias_deg: float = 0.5
    rangefinder: bool = True
    range_noise_m: float = 0.02
    baro: bool = True
    baro_noise_m: float = 0.2
    latency: tuple = (0.005, 0.02)
    # HEARTBEAT's armed flag (armed at `armed_at_s`) and EXTENDED_SYS_STATE's landed state
    flight_state: bool = True
    armed_at_s: float = 0.5


SENSOR_VARIANTS = {"full": SensorOptions(),
                   "rangefinder-only": SensorOptions(baro=False),
                   "baro-only": SensorOptions(rangefinder=False),
                   "no-imu": SensorOptions(imu=None),
                   "highres-imu": SensorOptions(imu="HIGHRES_IMU"),
                   "imu-only": SensorOptions(rangefinder=False, baro=False)}


@dataclass
class TrackerOptions:
    """How the simulated tracker sees the flight."""

    fps: float = 30.0
    start_s: float = 1.5
    # a new map's scale, like the real tracker's (vo init_map_depth): its median scene depth, the
    # camera's height over the flat ground, is map_depth units (later maps: up to a log-normal
    # error)
    map_depth: float = 1.0
    map_depth_error: float = 0.1
    noise_m: float = 0.02
    drift_per_sqrt_m: float = 0.01
    scale_walk_per_sqrt_s: float = 0.002
    rot_walk_deg_per_sqrt_s: float = 0.05
    lever: np.ndarray = field(default_factory=lambda: np.zeros(3))  # camera in body FRD, m
    cov_std_m: float = 0.02
    rot_noise_deg: float = 0.2
    scene_points: int = 0  # map points on the ground matched per frame (daemon scene.py)
    scene_noise: float = 0.02  # their depth noise, fraction of the height
    weak: tuple = ()  # (t0, t1) windows of 'insufficient' tracking
    lost: tuple = ()  # (t0, t1) windows without pose; a new map starts after each
    delay_s: float = 0.03  # capture -> result


@dataclass
class Flight:
    """Everything the estimator is fed, in arrival order, and the truth to score it."""

    truth: Truth
    messages: list = field(default_factory=list)  # (arrival, msg)
    frames: list = field(default_factory=list)  # (ready time, FrameResult, t_capture)
    map_scales: list = field(default_factory=list)  # VO units per metre of each map, at start
    compass_bias_deg: float = 0.0  # of the attitude the autopilot reports


def _wander(amplitude: float, rng: np.random.Generator):
    """t -> a body-axis offset (3,): per axis a sine of `amplitude` at a seeded 0.05-0.5 Hz."""
    hz, phase = rng.uniform(0.05, 0.5, 3), rng.uniform(0.0, 2 * np.pi, 3)
    return lambda t: amplitude * np.sin(2 * np.pi * hz * t + phase)


def autopilot_messages(truth: Truth, opt: SensorOptions, rng: np.random.Generator) -> list:
    """(arrival time on our clock, MAVLink message) for every stream, sorted by arrival."""
    out = []

    def emit(hz: float, make) -> None:
        for t in np.arange(0.0, truth.t[-1], 1.0 / hz):
            msg = make(truth.at(t), round(t * 1000))
            if msg is not None:
                out.append((t + BOOT_OFFSET + rng.uniform(*opt.latency), msg))

    if opt.flight_state:
        out += _flight_state_messages(truth, opt, rng)
    bias = np.array(opt.accel_bias)
    wander = _wander(opt.accel_wander, rng) if opt.accel_wander > 0.0 else (lambda t: 0.0)
    if opt.imu is not None:
        def imu(i: int, ms: int):
            acc = truth.f[i] + bias + wander(truth.t[i]) + rng.normal(0, opt.accel_noise, 3)
            if opt.imu == "HIGHRES_IMU":
                return mavlink2.MAVLink_highres_imu_message(ms * 1000, *acc, 0, 0, 0, 0, 0, 0,
                                                            0, 0, 0, 25, 0b111)
            mg = np.round(acc / 9.80665 * 1000).astype(int)
            return mavlink2.MAVLink_scaled_imu_message(ms, *mg, 0, 0, 0, 0, 0, 0)
        emit(opt.imu_hz, imu)

    def attitude(i: int, ms: int):
        noise = np.radians(rng.normal(0, [opt.tilt_noise_deg, opt.tilt_noise_deg,
                                          opt.heading_noise_deg]))
        yaw, pitch, roll = Rotation.from_matrix(truth.R[i]).as_euler("ZYX")
        return mavlink2.MAVLink_attitude_message(
            ms, roll + noise[0], pitch + noise[1],
            yaw + noise[2] + np.radians(opt.heading_bias_deg), 0, 0, 0)
    emit(opt.attitude_hz, attitude)

    if opt.rangefinder:
        def distance(i: int, ms: int):
            height = -truth.p[i, 2] + CAMERA_HEIGHT
            d = height / truth.R[i][2, 2] + rng.normal(0, opt.range_noise_m)
            return mavlink2.MAVLink_distance_sensor_message(
                ms, 10, 4000, round(100 * d), 0, 0,
                mavlink2.MAV_SENSOR_ROTATION_PITCH_270, 0)
        emit(10.0, distance)

    if opt.baro:
        drift = 0.0

        def pressure(i: int, ms: int):
            nonlocal drift
            drift += rng.normal(0, 0.005)
            alt = 120.0 - truth.p[i, 2] + drift + rng.normal(0, opt.baro_noise_m)
            hpa = 1013.25 * (1 - alt / 44330.77) ** (1 / 0.190263)
            return mavlink2.MAVLink_scaled_pressure_message(ms, hpa, 0.0, 2000)
        emit(10.0, pressure)
    out.sort(key=lambda item: item[0])
    return out


def _flight_state_messages(truth: Truth, opt: SensorOptions, rng: np.random.Generator) -> list:
    """HEARTBEAT at 1 Hz (armed from opt.armed_at_s; STANDBY while on the ground, as
    ArduCopter's) and EXTENDED_SYS_STATE at 5 Hz (on the ground while the vehicle has not left
    it), as (arrival, message)."""
    left = int(np.argmax((-truth.p[:, 2] > 0.02) | (np.linalg.norm(truth.v, axis=1) > 0.05)))
    out = []
    for t in np.arange(0.0, truth.t[-1], 1.0):
        armed = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if t >= opt.armed_at_s else 0
        status = mavlink2.MAV_STATE_STANDBY if truth.at(t) < left else mavlink2.MAV_STATE_ACTIVE
        out.append((t + BOOT_OFFSET, mavlink2.MAVLink_heartbeat_message(
            mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            armed | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, status, 3)))
    for t in np.arange(0.0, truth.t[-1], 0.2):
        landed = (mavlink2.MAV_LANDED_STATE_ON_GROUND if truth.at(t) < left
                  else mavlink2.MAV_LANDED_STATE_IN_AIR)
        out.append((t + BOOT_OFFSET + rng.uniform(*opt.latency),
                    mavlink2.MAVLink_extended_sys_state_message(0, landed)))
    return out


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    return Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()


def tracker_results(truth: Truth, opt: TrackerOptions, mounting: MountingConfig,
                    rng: np.random.Generator, scales: list | None = None) -> list:
    """(ready time, FrameResult, t_capture) at the tracker's frame rate. The tracker integrates
    the true motion in its own frame and scale, with random-walk drift of position (per metre),
    scale and rotation (per second), plus white noise on every pose. The scale of each new map
    (VO units per metre) is appended to `scales`."""
    R_b_c = body_from_camera(mounting)
    out, last_p, seg, dt = [], None, None, 1.0 / opt.fps
    scales = [] if scales is None else scales
    for t in np.arange(0.0, truth.t[-1], dt):
        i = truth.at(t)
        t_capture = t + BOOT_OFFSET
        if t < opt.start_s:  # the camera runs, the map does not exist yet
            out.append((t_capture + opt.delay_s, FrameResult(t, None, Quality.INITIALIZING),
                        t_capture))
            continue
        if any(a <= t < b for a, b in opt.lost):
            out.append((t_capture + opt.delay_s, FrameResult(t, None, Quality.LOST), t_capture))
            seg = None
            continue
        new = seg is None
        if new:
            depth = CAMERA_HEIGHT - truth.p[i, 2]
            error = rng.normal(0, opt.map_depth_error) if out else 0.0
            seg = {"R_w_n": _random_rotation(rng), "p_w": rng.normal(0, 2.0, 3),
                   "scale": opt.map_depth / depth * np.exp(error)}
            scales.append(seg["scale"])
        else:
            step = truth.p[i] + truth.R[i] @ opt.lever - last_p
            walk = rng.normal(0, opt.drift_per_sqrt_m * np.sqrt(np.linalg.norm(step)), 3)
            seg["p_w"] = seg["p_w"] + seg["scale"] * (seg["R_w_n"] @ (step + walk))
            seg["scale"] *= np.exp(rng.normal(0, opt.scale_walk_per_sqrt_s * np.sqrt(dt)))
            turn = np.radians(rng.normal(0, opt.rot_walk_deg_per_sqrt_s * np.sqrt(dt), 3))
            seg["R_w_n"] = seg["R_w_n"] @ Rotation.from_rotvec(turn).as_matrix()
        last_p = truth.p[i] + truth.R[i] @ opt.lever
        weak = any(a <= t < b for a, b in opt.weak)
        noise = opt.noise_m * (3.0 if weak else 1.0)
        scale, R_w_n = seg["scale"], seg["R_w_n"]
        rot_noise = Rotation.from_rotvec(np.radians(rng.normal(0, opt.rot_noise_deg, 3)))
        T = np.eye(4)
        T[:3, :3] = rot_noise.as_matrix() @ R_w_n @ truth.R[i] @ R_b_c
        T[:3, 3] = seg["p_w"] + scale * (R_w_n @ rng.normal(0, noise, 3))
        cov = np.diag([(scale * opt.cov_std_m * (3.0 if weak else 1.0)) ** 2] * 3
                      + [np.radians(opt.rot_noise_deg) ** 2] * 3)
        result = FrameResult(t, T, Quality.INSUFFICIENT if weak else Quality.GOOD, covariance=cov,
                             new_segment=new)
        if opt.scene_points:
            ground = _ground_points(truth.p[i] + truth.R[i] @ opt.lever, opt, rng)
            scene = seg["p_w"] + scale * (ground - last_p) @ R_w_n.T
            result = SceneResult(**vars(result), scene_w=scene)
        out.append((t_capture + opt.delay_s, result, t_capture))
    return out


def _ground_points(camera_n: np.ndarray, opt: TrackerOptions,
                   rng: np.random.Generator) -> np.ndarray:
    """Points of the flat ground (N's z = CAMERA_HEIGHT) in a downward camera's view, in N,
    their heights off by the map's depth noise."""
    height = CAMERA_HEIGHT - camera_n[2]
    points = np.empty((opt.scene_points, 3))
    points[:, :2] = camera_n[:2] + rng.uniform(-0.6, 0.6, (opt.scene_points, 2)) * height
    points[:, 2] = CAMERA_HEIGHT + rng.normal(0, opt.scene_noise * height, opt.scene_points)
    return points


def simulate(sensors: SensorOptions | None = None, tracker: TrackerOptions | None = None,
             mounting: MountingConfig | None = None, seed: int = 1,
             truth: Truth | None = None) -> Flight:
    """A flight with its message and frame streams."""
    rng = np.random.default_rng(seed)
    truth = truth or survey_flight()
    mounting = mounting or MountingConfig()
    sensors = sensors or SensorOptions()
    scales: list = []
    messages = autopilot_messages(truth, sensors, rng)
    frames = tracker_results(truth, tracker or TrackerOptions(), mounting, rng, scales)
    return Flight(truth, messages, frames, scales, sensors.heading_bias_deg)


def run(flight: Flight, estimator, timings: list | None = None) -> list:
    """Feed messages and frames in arrival order; (t_capture, estimate or None) per frame.
    `timings` collects the wall time of each on_frame call, seconds."""
    out, k = [], 0
    msgs = flight.messages
    clock = {"now": 0.0}
    estimator.now = lambda: clock["now"]
    for ready, result, t_capture in flight.frames:
        while k < len(msgs) and msgs[k][0] <= ready:
            clock["now"] = msgs[k][0]
            estimator.on_autopilot_message(msgs[k][1])
            k += 1
        clock["now"] = ready
        start = time.perf_counter()
        out.append((t_capture, estimator.on_frame(result, t_capture)))
        if timings is not None:
            timings.append(time.perf_counter() - start)
    return out


@dataclass
class Score:
    """Accuracy of the published estimates against the truth."""

    published: int
    first_published_s: float
    position_rmse_m: float
    distance_m: float
    heading_rms_deg: float
    velocity_rmse_m_s: float
    nees_position: float  # mean NEES per degree of freedom
    nees_velocity: float
    overconfident_fraction: float = 0.0  # position error beyond 3 sigma (chi-square, 3 dof)

    @property
    def position_pct(self) -> float:
        """Position RMSE in percent of the distance flown while published."""
        return 100.0 * self.position_rmse_m / max(self.distance_m, 1e-9)

    def to_dict(self) -> dict:
        """Plain floats, for JSON."""
        return {**{k: float(v) for k, v in asdict(self).items()},
                "position_pct": self.position_pct}


def score(flight: Flight, estimates: list, from_s: float = 0.0) -> Score:
    """Compare the estimates published from flight time `from_s` on with the truth, from the
    first of them on (positions relative to it): no other alignment. With from_s = 0 that is
    the local frame's own origin, where the vehicle started. NEES in the autopilot's heading
    frame (sim/replay/fusion_scores.py)."""
    truth = flight.truth
    published = [(t_capture, e) for t_capture, e in estimates
                 if e is not None and t_capture - BOOT_OFFSET >= from_s]
    if published:
        first_t, first = published[0]
        start = truth.p[truth.at(first_t - BOOT_OFFSET)]
    pos_err, head_err, vel_err, nees, nees_v, times = [], [], [], [], [], []
    for t_capture, e in published:
        t = t_capture - BOOT_OFFSET
        i = truth.at(t)
        moved = np.array([truth.p[i] - start, truth.v[i]])
        moved_frame = turned_about_down(moved, flight.compass_bias_deg)
        pos_err.append(e.position - first.position - moved[0])
        vel_err.append(e.velocity_local - moved[1])
        err = e.position - first.position - moved_frame[0]
        err_b = e.R_local_body.T @ (e.velocity_local - moved_frame[1])
        nees_v.append(err_b @ np.linalg.solve(e.velocity_covariance[:3, :3], err_b) / 3.0)
        nees.append(err @ np.linalg.solve(e.pose_covariance[:3, :3], err) / 3.0)
        R = e.R_local_body @ truth.R[i].T
        head_err.append(np.degrees(np.arctan2(R[1, 0], R[0, 0])))
        times.append(t)
    if not times:
        return Score(0, np.inf, np.inf, 0.0, np.inf, np.inf, np.inf, np.inf, 1.0)
    rms = lambda a: float(np.sqrt(np.mean(np.sum(np.square(a), axis=-1))))  # noqa: E731
    beyond = float(np.mean(3.0 * np.array(nees) > CHI2_3DOF_3SIGMA))
    return Score(len(times), times[0], rms(np.array(pos_err)), truth.distance(times[0], times[-1]),
                 rms(np.array(head_err)[:, None]), rms(np.array(vel_err)), float(np.mean(nees)),
                 float(np.mean(nees_v)), beyond)


def fusion_config(**changes: object) -> FusionConfig:
    """The filter's defaults for this simulated tracker: it reports its true position noise, so
    the factor the real tracker needs (vo_covariance_factor) stays 1."""
    return FusionConfig(**{"vo_covariance_factor": 1.0, **changes})

