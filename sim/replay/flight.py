"""The flight the simulated autopilot replays: the vehicle (body FRD) in NED from a sequence's
camera ground truth, and the sensor streams that make sense for it.

Synthetic flights (sim.synth) say `extras["world"] == "NED"`, bring their camera mounting as
`extras["T_b_c"]` and record their IMU in the body frame. Another sequence whose ground-truth
world is not NED may say how it relates in `extras["T_ned_world"]` (4x4); without it the
ground-truth world is taken as NED (datasets recorded by hand have no gravity reference; the
scores use a Sim(3) alignment then anyway). Recorded IMU samples are streamed instead of the ones
derived from the ground truth when they are in the body frame (synthetic flights, or
`extras["imu_frame"] == "body_frd"`).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from daemon.config import Config, MountingConfig, replace
from daemon.fusion.config import FusionConfig
from daemon.mounting import (
    PRESET_ANGLES_DEG,
    R_BODY_FORWARD_CAMERA,
    body_from_camera,
    body_T_camera,
)
from sim.autopilot.simulator import DEFAULT_STREAMS
from sim.sequence import ImuSamples
from sim.trajectory import Trajectory

RANGEFINDER_M = (0.2, 40.0)  # DISTANCE_SENSOR min and max distance the simulator encodes
RESAMPLE_HZ = 200.0
# the autopilot's message streams of each sensor a replay can leave out
SENSOR_STREAMS = {"imu": ("SCALED_IMU", "HIGHRES_IMU", "RAW_IMU"),
                  "baro": ("SCALED_PRESSURE", "ALTITUDE"),
                  "rangefinder": ("DISTANCE_SENSOR",)}


def is_ned(sequence: object) -> bool:
    """Whether the sequence says where NED is (synthetic flights do); a hand-held dataset's
    world has no known down."""
    extras = getattr(sequence, "extras", {})
    return extras.get("world") == "NED" or "T_ned_world" in extras


def drone_config(config: Config, sequence: object) -> Config:
    """The config describing the drone that flew: the sequence's own camera mounting
    (`extras["T_b_c"]`: rotation as the mounting, lever arm as the fusion's camera position)
    and its sensors' datasheet (`extras["sensor_noise"]`, sim.synth.sensors.SensorNoise) as
    the fusion's sensor noise where `config` keeps the defaults, as a user enters their own;
    unchanged for sequences that bring neither."""
    extras = getattr(sequence, "extras", {})
    noise = extras.get("sensor_noise")
    if noise is not None:
        default = FusionConfig()
        config = replace(config, fusion={
            key: value for key, value in noise.fusion_settings().items()
            if getattr(config.fusion, key) == getattr(default, key)})
    T_b_c = extras.get("T_b_c")
    if T_b_c is None:
        return config
    T_b_c = np.asarray(T_b_c, dtype=np.float64)
    x, y, z = (float(v) for v in T_b_c[:3, 3])
    lever = {"camera_x_m": x, "camera_y_m": y, "camera_z_m": z}
    for preset in PRESET_ANGLES_DEG:
        if np.allclose(body_from_camera(MountingConfig(preset=preset)), T_b_c[:3, :3],
                       atol=1e-9):
            return replace(config, mounting={"preset": preset}, fusion=lever)
    yaw, pitch, roll = np.degrees(Rotation.from_matrix(
        T_b_c[:3, :3] @ R_BODY_FORWARD_CAMERA.T).as_euler("ZYX"))
    return replace(config, mounting={"preset": "custom", "roll_deg": float(roll),
                                     "pitch_deg": float(pitch), "yaw_deg": float(yaw)},
                   fusion=lever)


def vehicle_trajectory(groundtruth: Trajectory, config: Config,
                       T_ned_world: np.ndarray | None = None) -> Trajectory:
    """T_ned_b(t) = T_ned_w T_w_c(t) T_c_b: where the body is when the camera is at T_w_c, with
    the config's mounting and camera lever arm."""
    T_ned_w = np.eye(4) if T_ned_world is None else np.asarray(T_ned_world, dtype=np.float64)
    return Trajectory.from_matrices(groundtruth.t, T_ned_w @ groundtruth.matrices()
                                    @ np.linalg.inv(body_T_camera(config)))


def resampled(flight: Trajectory, rate_hz: float = RESAMPLE_HZ) -> Trajectory:
    """The flight on a dense grid through a cubic spline, so the simulator's finite-difference
    accelerations (linear interpolation between samples) are smooth even for ground truth
    sampled at the frame rate."""
    if len(flight) < 4:
        return flight
    t = np.arange(flight.t[0], flight.t[-1], 1.0 / rate_hz)
    positions = CubicSpline(flight.t, flight.positions, axis=0)(t)
    quaternions = Slerp(flight.t, flight.rotations)(t).as_quat()
    return Trajectory(np.append(t, flight.t[-1]), np.vstack([positions, flight.positions[-1:]]),
                      np.vstack([quaternions, flight.quaternions[-1:]]))


def body_imu(sequence: object) -> ImuSamples | None:
    """The sequence's recorded IMU when it is in body FRD, else None (derive it)."""
    imu = getattr(sequence, "imu", None)
    extras = getattr(sequence, "extras", {})
    in_body = extras.get("world") == "NED" or extras.get("imu_frame") == "body_frd"
    return imu if imu is not None and in_body else None


def recorded_sensors(sequence: object) -> dict:
    """What the replayed vehicle reads from the sequence's recordings (AutopilotProcess's
    imu, sensors and imu_bias): its body IMU, a synthetic flight's attitude, barometer and
    rangefinder, and its IMU's true bias (for the pre-flight)."""
    extras = getattr(sequence, "extras", {})
    return {"imu": body_imu(sequence), "sensors": extras.get("sensors"),
            "imu_bias": extras.get("imu_bias")}


def absent_sensors(flight: Trajectory | None, without: tuple[str, ...] = ()) -> frozenset[str]:
    """The sensor messages the replayed vehicle cannot send: those of the sensor kinds in
    `without` (SENSOR_STREAMS), and the rangefinder's unless the whole flight stays within its
    range above the flat ground at NED z = 0 (a hand-held dataset's 'height' means nothing)."""
    absent = {name for kind in without for name in SENSOR_STREAMS[kind]}
    if flight is not None:
        height = -flight.positions[:, 2]
        if height.min() < RANGEFINDER_M[0] or height.max() > RANGEFINDER_M[1]:
            absent.add("DISTANCE_SENSOR")
    return frozenset(absent)


def sensor_streams(flavour: str, flight: Trajectory | None,
                   without: tuple[str, ...] = ()) -> dict[str, float]:
    """The flavour's usual streams but those the vehicle cannot send (absent_sensors)."""
    absent = absent_sensors(flight, without)
    return {k: v for k, v in DEFAULT_STREAMS[flavour].items() if k not in absent}
