"""Named synthetic flights, deterministic for a seed: the body path, the world, the camera and
its mounting, imaging effects and events."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.camera import CameraModel
from sdvl.errors import InputError
from sim.synth.effects import Effects
from sim.synth.events import Interval, crowd_leaving, walkers_across
from sim.synth.scene import Scene
from sim.synth.trajectory_gen import BodyPath, path_from_waypoints, rounded_polyline, travel
from sim.synth.worlds import DETAIL, outdoor_scene, room_scene

FPS = 30.0
BASE_CAMERA = CameraModel(640, 480, 480.0, 480.0, 319.5, 239.5)
HANDHELD_CAMERA = CameraModel(640, 480, 460.0, 460.0, 319.5, 239.5, "radtan_opencv",
                              (-0.06, 0.012, 0.0, 0.0))


def mounting(R_b_c, lever) -> np.ndarray:
    """T_b_c from the camera axes in body coordinates and the lever arm (m)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R_b_c, float)
    T[:3, 3] = lever
    return T


# camera x = body right, y = body backward, z = body down
T_B_C_DOWN = mounting([[0, -1, 0], [1, 0, 0], [0, 0, 1]], (0.05, 0.0, 0.04))
# camera x = body right, y = body down, z = body forward
T_B_C_FORWARD = mounting([[0, 0, 1], [1, 0, 0], [0, 1, 0]], (0.05, 0.0, 0.0))


@dataclass
class FlightSpec:
    """Everything a synthetic sequence is made from."""

    path: BodyPath
    scene: Scene
    camera: CameraModel = BASE_CAMERA
    T_b_c: np.ndarray = field(default_factory=lambda: T_B_C_DOWN.copy())
    effects: Effects = field(default_factory=Effects)
    blackouts: tuple[Interval, ...] = ()
    gaps: tuple[Interval, ...] = ()
    fps: float = FPS
    # the depth camera of sim.synth.depth_sensor.SENSORS the depth maps are measured with:
    # outdoors the longer-baseline D455 (2% at 4 m), indoors the D435 (min depth 0.28 m)
    depth_sensor: str = "d455"


def _hover_path(rng: np.random.Generator, altitude: float, duration: float,
                start_alt: float | None = None, yaw_turn: float = 0.0) -> BodyPath:
    """Climb from `start_alt` to `altitude`, hold with a slow +-0.4 m wander and turn by
    `yaw_turn` rad in the middle third."""
    t = np.arange(0.0, duration + 1e-9, 1.5)
    pos = np.column_stack([rng.uniform(-0.4, 0.4, t.size), rng.uniform(-0.4, 0.4, t.size),
                           np.full(t.size, -altitude)])
    pos[0] = (0.0, 0.0, -(start_alt or altitude))
    climb = min(6.0, duration / 3)
    pos[t < climb, 2] = -np.interp(t[t < climb], [0, climb], [start_alt or altitude, altitude])
    yaw = yaw_turn * np.clip((t - duration / 3) / (duration / 3), 0, 1)
    return path_from_waypoints(t, pos, yaw)


def hover_down(seed: int, textures: str | None) -> FlightSpec:
    """Take-off from 1.5 m to 6 m, hold with a slow wander, a 90 degree yaw turn; 20 s."""
    rng = np.random.default_rng(seed)
    path = _hover_path(rng, 6.0, 20.0, start_alt=1.5, yaw_turn=np.pi / 2)
    return FlightSpec(path, outdoor_scene(seed, textures))


def _survey_path(altitude: float, legs: int, leg_m: float, spacing: float, speed: float,
                 dt: float = 0.5) -> BodyPath:
    """Lawnmower survey at constant altitude and heading north, rounded turns."""
    corners = []
    for k in range(legs):
        y = (k - (legs - 1) / 2) * spacing
        xs = (-leg_m / 2, leg_m / 2) if k % 2 == 0 else (leg_m / 2, -leg_m / 2)
        corners += [(xs[0], y, -altitude), (xs[1], y, -altitude)]
    t, pos = travel(rounded_polyline(np.array(corners), spacing / 2), speed, dt=dt)
    return path_from_waypoints(t, pos, np.zeros_like(t))


def survey_down(seed: int, textures: str | None) -> FlightSpec:
    """Lawnmower survey at 12 m, 3 legs of 30 m, 8 m apart, 3 m/s (about 37 s)."""
    return FlightSpec(_survey_path(12.0, 3, 30.0, 8.0, 3.0), outdoor_scene(seed, textures))


def survey_low(seed: int, textures: str | None) -> FlightSpec:
    """Lawnmower survey at 5 m, 3 legs of 30 m, 4 m apart, 2 m/s (about 55 s): within a depth
    camera's range (D455: ideal up to 6 m)."""
    return FlightSpec(_survey_path(5.0, 3, 30.0, 4.0, 2.0), outdoor_scene(seed, textures))


def survey_long(seed: int, textures: str | None) -> FlightSpec:
    """The survey for hours of tracking: 10 legs of 100 m at 12 m, 8 m apart, 3 m/s (about
    6 min, 10,800 frames): the map must stay bounded while the camera keeps seeing new ground."""
    return FlightSpec(_survey_path(12.0, 10, 100.0, 8.0, 3.0), outdoor_scene(seed, textures))


def room_handheld(seed: int, textures: str | None) -> FlightSpec:
    """A camera carried at 1.5 m through a room: sideways walks facing the walls, a pan on the
    spot (pure rotation), head bob; about 26 s."""
    rng = np.random.default_rng(seed)
    keys = np.array([  # t, x, y, yaw (deg), pitch (deg)
        (0, -2.5, -0.5, 90, -5), (4, -0.5, -0.5, 90, -8), (8, 1.5, -0.5, 95, -5),
        (10, 1.5, -0.5, 60, -5), (13, 1.5, -0.5, 140, -10), (15, 1.5, -0.5, 100, -5),
        (19, 0.0, 0.5, 160, -8), (23, -2.0, 0.5, 200, -5), (26, -2.5, 0.0, 200, -5)])
    t = np.arange(0.0, keys[-1, 0] + 1e-9, 0.5)
    x, y = (np.interp(t, keys[:, 0], keys[:, k]) for k in (1, 2))
    z = -1.5 + 0.02 * np.sin(2 * np.pi * 1.8 * t) + rng.normal(0, 0.005, t.size)
    yaw = np.radians(np.interp(t, keys[:, 0], keys[:, 3]))
    pitch = np.radians(np.interp(t, keys[:, 0], keys[:, 4])) + rng.normal(0, 0.01, t.size)
    roll = rng.normal(0, 0.01, t.size)
    path = path_from_waypoints(t, np.column_stack([x, y, z]), yaw, pitch, roll)
    return FlightSpec(path, room_scene(seed, textures), HANDHELD_CAMERA, T_B_C_FORWARD.copy(),
                      depth_sensor="d435")


def _stop_and_go(altitude: float, before: float, stop: float, after: float, speed: float,
                 rng: np.random.Generator) -> tuple[BodyPath, float]:
    """North `before` m to the origin, hold there `stop` s with a +-0.1 m wander, north
    `after` m more: the path, and when the hold starts."""
    t1, p1 = travel(np.array([(-before, 0, -altitude), (0, 0, -altitude)], float), speed,
                    ramp_s=1.5)
    th = t1[-1] + np.arange(0.5, stop, 0.5)
    ph = np.column_stack([rng.uniform(-0.1, 0.1, (th.size, 2)), np.full(th.size, -altitude)])
    t2, p2 = travel(np.array([(0, 0, -altitude), (after, 0, -altitude)], float), speed,
                    ramp_s=1.5)
    t = np.concatenate([t1, th, t2 + t1[-1] + stop])
    pos = np.vstack([p1, ph, p2])
    return path_from_waypoints(t, pos, np.zeros_like(t)), float(t1[-1])


def walkers(seed: int, textures: str | None) -> FlightSpec:
    """A slow survey leg at 5 m over a square: the drone flies north over a group of 14
    people standing below it (mapped on the way in: their heads are 1.7 m closer than the
    ground), holds there while the group walks off together, and flies on; 6 more people walk
    through the view. Each person is about 75 x 45 px seen from above; people cover about a
    third of the view while the drone holds above the group (0.34 at 5 s, 0.14 at 9.5 s);
    16 s. `walkers_empty` is the same flight with nobody on the square."""
    rng = np.random.default_rng(seed)
    path, hold = _stop_and_go(5.0, 5.0, 5.0, 5.0, 1.2, rng)
    spec = FlightSpec(path, outdoor_scene(seed, textures))
    spec.scene.movers = (crowd_leaving((0.3, 0.0), 14, (3.0, 4.0), hold + 1.0,
                                       rng.uniform(0, 2 * np.pi), DETAIL, rng)
                         + walkers_across((0.0, 0.0), 4.0, 6, path.duration, DETAIL, rng))
    return spec


def walkers_empty(seed: int, textures: str | None) -> FlightSpec:
    """The walkers flight with nobody on the square (the calm reference)."""
    spec = walkers(seed, textures)
    spec.scene.movers = []
    return spec


def _out_and_back(altitude: float, length: float, speed: float,
                  offset: float = 6.0) -> BodyPath:
    """Out `length` m north, `offset` m east, and back south."""
    corners = np.array([(0, 0, -altitude), (length, 0, -altitude), (length, offset, -altitude),
                        (0, offset, -altitude)], float)
    t, pos = travel(rounded_polyline(corners, offset / 2), speed)
    return path_from_waypoints(t, pos, np.zeros_like(t))


def blackout(seed: int, textures: str | None) -> FlightSpec:
    """Out 30 m and back 3 m to the side at 10 m altitude; the lens is covered for 3 s at the
    far turn, then the camera sees the ground it mapped on the way out again (about 60% of
    the view when it returns; 6 m to the side it was a third)."""
    path = _out_and_back(10.0, 30.0, 2.5, offset=3.0)
    mid = path.duration / 2
    return FlightSpec(path, outdoor_scene(seed, textures),
                      blackouts=(Interval(mid - 1.5, mid + 1.5),))


def kidnap(seed: int, textures: str | None) -> FlightSpec:
    """The out-and-back flight with no frames for 4 s at the far turn (the video jumps)."""
    path = _out_and_back(10.0, 30.0, 2.5)
    mid = path.duration / 2
    return FlightSpec(path, outdoor_scene(seed, textures), gaps=(Interval(mid - 2, mid + 2),))


def fast_down(seed: int, textures: str | None) -> FlightSpec:
    """Low (5 m) and fast (6 m/s) lawnmower with a longer shutter: motion blur."""
    return FlightSpec(_survey_path(5.0, 2, 40.0, 12.0, 6.0), outdoor_scene(seed, textures),
                      effects=Effects(shutter=0.008))


PRESETS: dict[str, Callable[[int, str | None], FlightSpec]] = {
    "hover-down": hover_down,
    "survey-down": survey_down,
    "survey-low": survey_low,
    "survey-long": survey_long,
    "room-handheld": room_handheld,
    "walkers": walkers,
    "walkers-empty": walkers_empty,
    "blackout": blackout,
    "kidnap": kidnap,
    "fast-down": fast_down,
}


def preset_spec(name: str, seed: int = 0, textures: str | None = "auto") -> FlightSpec:
    """The FlightSpec of a named preset; InputError naming the known ones otherwise."""
    if name not in PRESETS:
        raise InputError(f"unknown preset '{name}' (known: {', '.join(PRESETS)})")
    return PRESETS[name](seed, textures)
