"""The synthetic world a closed-loop flight sees: a preset's scene, camera, camera mounting and
image effects (sim/synth), rendered wherever the vehicle truly is.

The image is the ray-cast scene at the camera pose T_ned_body T_b_c, with the preset's
vignetting, exposure drift and sensor noise (deterministic for the seed and frame number); with
a depth camera, the depth map the preset's sensor model (sim.synth.depth_sensor) measures from
the same ray cast.
Motion blur is left out: it needs the poses over the shutter time, and a closed loop knows only
the present one (4 ms of shutter at the default mission's speeds is under a pixel at 3 m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.camera import CameraModel
from sim.synth.depth_sensor import depth_sensor, measure_depth
from sim.synth.effects import exposure_gain, finish
from sim.synth.flight import camera_for_size
from sim.synth.presets import FlightSpec, preset_spec
from sim.synth.raycast import cast_ray, render_surfaces


@dataclass
class FlightWorld:
    """A preset's world, its camera at the chosen size, and the mounting T_b_c."""

    spec: FlightSpec
    camera: CameraModel
    seed: int

    @classmethod
    def of_preset(cls, preset: str, seed: int, size: tuple[int, int] | None = None,
                  textures: str | None = "auto") -> FlightWorld:
        spec = preset_spec(preset, seed, textures)
        return cls(spec, camera_for_size(spec.camera, size), seed)

    @property
    def T_b_c(self) -> np.ndarray:
        return self.spec.T_b_c

    def drone(self) -> object:
        """What `sim.replay.flight.drone_config` reads of a flight: the camera mounting only.
        The fusion keeps its default sensor noise, as for a user who does not know the
        autopilot's sensors (the simulated autopilot's are not the synthetic flights')."""
        return _Drone({"T_b_c": self.T_b_c.copy()})

    def range(self, origin: np.ndarray, direction: np.ndarray) -> float:
        """Distance (m) along a unit NED ray to the world's static surfaces (inf: none), for
        the autopilot's rangefinder."""
        return float(cast_ray(self.spec.scene.quads.geometry, *origin, *direction))

    def image(self, index: int, t: float, T_ned_body: np.ndarray) -> np.ndarray:
        """The uint8 frame the camera takes at time t with the body at T_ned_body."""
        return self.frame(index, t, T_ned_body, depth=False)[0]

    def frame(self, index: int, t: float, T_ned_body: np.ndarray,
              depth: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """The uint8 frame at time t with the body at T_ned_body, and with `depth` the depth
        map (float32 m, 0 = none) the preset's depth camera measures (registered to the
        image; seeded per frame)."""
        T_w_c = T_ned_body @ self.T_b_c
        surfaces = render_surfaces(self.spec.scene, self.camera, T_w_c, t)
        phase = float(np.random.default_rng(self.seed).uniform(0, 2 * np.pi))
        gain = exposure_gain(self.spec.effects, t, phase)
        rng = np.random.default_rng([self.seed, index])
        image = finish(surfaces.image, self.camera, self.spec.effects, gain, rng)
        if not depth:
            return image, None
        measured = measure_depth(depth_sensor(self.spec.depth_sensor), surfaces, self.camera,
                                 T_w_c, self.spec.scene.glossy,
                                 np.random.default_rng([self.seed, index, 3]))
        return image, measured


@dataclass(frozen=True)
class _Drone:
    extras: dict
