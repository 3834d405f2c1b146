"""Synthetic sequences in memory: frames rendered lazily, exact ground truth, IMU and autopilot
signals from the same trajectory.

Frames: NED world (x north, y east, z down, ground at z = 0), camera x right y down z forward.
`synthetic_sequence(preset)` returns a `sim.sequence.Sequence` with

- `groundtruth`: T_w_c (camera in the NED world) at every frame time (TUM convention);
- `imu`: ImuSamples at 200 Hz in the body frame (FRD, at the body origin): accel is the specific
  force including gravity (about (0, 0, -9.81) level at rest), gyro rad/s; with white noise and
  random-walking biases (`sim.synth.sensors.SensorNoise`);
- `extras`:
  - "sensors": SensorSamples at 50 Hz: attitude (xyzw quaternion R_ned_body, with noise and a
    constant heading error), baro_alt (m up from z = 0, noise and drift), range (m along the body
    down axis to the scene, `range_valid` within 0.2-40 m);
  - "T_b_c": 4x4 body-from-camera; "world": "NED"; "gravity": m/s^2;
  - "imu_clean": the IMU without noise or bias; "imu_bias": (accel, gyro) true biases (N, 3);
  - "blackouts" / "gaps": (start, end) seconds when the lens is covered / no frames come;
  - "sensor_noise": the SensorNoise the sensors were made with (their datasheet);
  - "depth_sensor": the DepthSensor the depth maps are measured with;
  - "preset", "seed", "path" (the BodyPath, for T_w_b at any time);
- `depth_loader`: the depth map of frame i as the preset's depth camera
  (sim.synth.depth_sensor) measures it, rendered when asked for.
Frame timestamps start at 0 s; frames inside gaps are missing (timestamps jump).
"""

from __future__ import annotations

import numpy as np

from calib.camera import CameraModel
from sdvl.errors import InputError
from sim.sequence import Sequence
from sim.synth.depth_sensor import DepthSensor, depth_sensor, measure_depth
from sim.synth.effects import DARK_LEVEL, exposure_gain, finish, subframe_count
from sim.synth.events import frame_times
from sim.synth.presets import FlightSpec, preset_spec
from sim.synth.raycast import Surfaces, render_surfaces
from sim.synth.sensors import (
    IMU_RATE,
    SENSOR_RATE,
    SensorNoise,
    autopilot_sensors,
    imu_clean,
    imu_measured,
    sample_times,
)
from sim.synth.trajectory_gen import GRAVITY
from sim.trajectory import Trajectory


def camera_for_size(camera: CameraModel, size: tuple[int, int] | None) -> CameraModel:
    """The preset camera for another image size: same field of view across the width, square
    pixels, centred principal point."""
    if size is None:
        return camera
    w, h = size
    if w < 16 or h < 16:
        raise InputError(f"image size {w}x{h} is too small (at least 16x16)")
    s = w / camera.width
    return CameraModel(w, h, camera.fx * s, camera.fy * s, (w - 1) / 2, (h - 1) / 2,
                       camera.distortion_model, camera.distortion)


def camera_poses(spec: FlightSpec, t: np.ndarray) -> np.ndarray:
    """T_w_c (N, 4, 4) at times t."""
    return spec.path.poses(t) @ spec.T_b_c


class FrameRenderer:
    """Renders frame i of a flight on demand, with effects; deterministic for (seed, i)."""

    def __init__(self, spec: FlightSpec, camera: CameraModel, times: np.ndarray, seed: int):
        self.spec, self.camera, self.times, self.seed = spec, camera, times, seed
        self.phase = float(np.random.default_rng(seed).uniform(0, 2 * np.pi))
        self._last: tuple[float, Surfaces] | None = None  # a frame's image and depth share it

    def surfaces(self, t: float) -> Surfaces:
        """What the camera sees at time t, without effects (the last one is kept)."""
        last = self._last  # read once: another thread may replace it meanwhile
        if last is None or last[0] != t:
            pose = camera_poses(self.spec, np.array([t]))[0]
            last = self._last = (t, render_surfaces(self.spec.scene, self.camera, pose, t))
        return last[1]

    def ideal(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Image (float32) and depth without effects at time t."""
        surfaces = self.surfaces(t)
        return surfaces.image, surfaces.depth

    def blurred(self, t: float) -> np.ndarray:
        """The image averaged over the shutter time (as many sub-frames as motion needs)."""
        image, depth = self.ideal(t)
        fx = self.spec.effects
        if fx.max_subframes <= 1:
            return image
        speed = float(np.linalg.norm(self.spec.path.velocity(t)))
        rate = float(np.linalg.norm(self.spec.path.gyro(t)))
        finite = depth[np.isfinite(depth)]
        near = float(np.percentile(finite, 5)) if finite.size else 1.0
        n = subframe_count(fx, self.camera.fx, speed, rate, near)
        if n <= 1:
            return image
        offsets = (np.arange(n) / (n - 1) - 0.5) * fx.shutter
        return np.mean([self.ideal(t + dt)[0] for dt in offsets], axis=0)

    def __call__(self, i: int) -> np.ndarray:
        t = float(self.times[i])
        rng = np.random.default_rng([self.seed, i])
        covered = any(b.contains(t) for b in self.spec.blackouts)
        if covered:
            image = np.full((self.camera.height, self.camera.width), DARK_LEVEL, np.float32)
        else:
            image = self.blurred(t)
        gain = exposure_gain(self.spec.effects, t, self.phase)
        return finish(image, self.camera, self.spec.effects, gain, rng)

    def depth(self, i: int, sensor: DepthSensor) -> np.ndarray:
        """Frame i's depth map as `sensor` measures it (seeded per frame; none while the lens
        is covered)."""
        t = float(self.times[i])
        if any(b.contains(t) for b in self.spec.blackouts):
            return np.zeros((self.camera.height, self.camera.width), np.float32)
        pose = camera_poses(self.spec, np.array([t]))[0]
        return measure_depth(sensor, self.surfaces(t), self.camera, pose,
                             self.spec.scene.glossy, np.random.default_rng([self.seed, i, 3]))


def synthetic_sequence(preset: str, frames: int | None = None,
                       size: tuple[int, int] | None = None, seed: int = 0,
                       textures: str | None = "auto",
                       noise: SensorNoise | None = None,
                       depth: str | None = None) -> Sequence:
    """A preset flight as an in-memory Sequence (see the module docstring for its contents).

    `frames` keeps the first N frames (and the sensors up to the last one); `textures` is
    'auto' (shared photos when present), 'procedural' (no files) or a folder of images;
    `depth` names the depth camera (sim.synth.depth_sensor.SENSORS; default the preset's).
    """
    spec = preset_spec(preset, seed, textures)
    times = frame_times(spec.path.duration, spec.fps, spec.gaps)
    if frames is not None:
        if frames < 1:
            raise InputError(f"--frames must be at least 1, got {frames}")
        times = times[:frames]
    camera = camera_for_size(spec.camera, size)
    end = float(times[-1])
    rng = np.random.default_rng([seed, 7])
    clean = imu_clean(spec.path, sample_times(end, IMU_RATE))
    noise = noise or SensorNoise()
    imu, ba, bg = imu_measured(clean, noise, rng)
    sensors = autopilot_sensors(spec.path, spec.scene, sample_times(end, SENSOR_RATE), noise,
                                rng)
    sensor = depth_sensor(depth or spec.depth_sensor)
    renderer = FrameRenderer(spec, camera, times, seed)
    extras = {"sensors": sensors, "T_b_c": spec.T_b_c.copy(), "world": "NED",
              "gravity": GRAVITY, "imu_clean": clean, "imu_bias": (ba, bg),
              "blackouts": [(b.start, b.end) for b in spec.blackouts],
              "gaps": [(g.start, g.end) for g in spec.gaps],
              "sensor_noise": noise, "depth_sensor": sensor, "preset": preset, "seed": seed,
              "path": spec.path}
    return Sequence(preset, camera, times, image_loader=renderer,
                    groundtruth=Trajectory.from_matrices(times, camera_poses(spec, times)),
                    imu=imu, extras=extras, depth_loader=lambda i: renderer.depth(i, sensor))
