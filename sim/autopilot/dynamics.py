"""The flying vehicle of a simulated autopilot: `SimOptions(dynamics=Dynamics(...))` puts a
multicopter on flat ground at a start pose; the model's `step(now)` advances its physics,
sensors, estimator and controllers on the model's clock. Its true pose and velocity are here for
whoever renders the camera or scores the flight (`T_ned_body`, `velocity_ned`); everything else
goes over MAVLink, as with a real vehicle.

Times given to `state(t)` are seconds since power-on (the model's uptime until its first
reboot), like the scripted Vehicle's.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from sim.autopilot.airframe import Airframe
from sim.autopilot.barometer import BaroSpec
from sim.autopilot.imu import ImuSpec
from sim.autopilot.multicopter import Multicopter
from sim.autopilot.rangefinder import RangefinderSpec
from sim.autopilot.wind import Wind, WindField

HISTORY_S = 2.0  # how far back state(t) can look (a late vision message's capture time)

# ray caster for the rangefinder: (origin NED, unit direction NED) -> distance m, inf = no hit
RangeFunction = Callable[[np.ndarray, np.ndarray], float]


@dataclass(frozen=True)
class Dynamics:
    """A multicopter standing on flat ground: its body origin above (north_m, east_m), heading
    yaw_deg, the ground at NED z = ground_down_m (the body origin is the airframe's gear height
    above it). `terrain` optionally replaces the flat ground for the rangefinder (a synthetic
    world's ray caster); the physics always stands on the flat ground. `rangefinder` None:
    the vehicle has none (no DISTANCE_SENSOR); `baro` its barometer (the rotors' wash and
    ground effect on it), `imu` its flight controller's IMU; `seed` draws its sensors' errors
    and noise."""

    north_m: float = 0.0
    east_m: float = 0.0
    yaw_deg: float = 0.0
    ground_down_m: float = 0.0
    airframe: Airframe = field(default_factory=Airframe)
    wind: Wind | None = None
    terrain: RangeFunction | None = None
    rangefinder: RangefinderSpec | None = field(default_factory=RangefinderSpec)
    baro: BaroSpec = field(default_factory=BaroSpec)
    imu: ImuSpec = field(default_factory=ImuSpec)
    seed: int = 0

    def hardware_params(self) -> dict[str, float]:
        """Parameters the builder set for this vehicle's hardware (its rangefinder)."""
        return {} if self.rangefinder is None else self.rangefinder.ardupilot_params()


@dataclass(frozen=True)
class TrueState:
    """The vehicle's truth at one time (body origin, NED)."""

    t: float
    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray  # body -> NED
    rates: np.ndarray  # body, rad/s
    specific_force: np.ndarray  # body, m/s^2

    def as_dict(self) -> dict:
        """The scripted Vehicle.state() layout (rotation as a scipy Rotation)."""
        return {"position": self.position, "velocity": self.velocity,
                "rotation": Rotation.from_matrix(self.rotation), "rates": self.rates,
                "specific_force": self.specific_force}


class FlyingVehicle:
    """Physics plus a short truth history. `advance(dt, command)` is called by the flight
    controller's fast loop; `mark()` keeps the current state for `state(t)`."""

    def __init__(self, dynamics: Dynamics) -> None:
        self.dynamics = dynamics
        self.body = Multicopter(dynamics.airframe, np.array([dynamics.north_m, dynamics.east_m]),
                                np.radians(dynamics.yaw_deg), dynamics.ground_down_m,
                                WindField(dynamics.wind))
        self.time = 0.0
        self._history: deque[TrueState] = deque()
        self.mark()

    # --- the interface for renderers and scorers --------------------------------------------

    @property
    def T_ned_body(self) -> np.ndarray:
        """4x4 pose of the body (FRD, origin at the IMU) in NED, now."""
        T = np.eye(4)
        T[:3, :3] = self.body.rotation
        T[:3, 3] = self.body.position
        return T

    @property
    def velocity_ned(self) -> np.ndarray:
        return self.body.velocity.copy()

    @property
    def on_ground(self) -> bool:
        return self.body.on_ground

    # --- stepping ---------------------------------------------------------------------------

    def advance(self, dt: float, command: np.ndarray) -> None:
        self.body.step(dt, command)
        self.time += dt

    def now(self) -> TrueState:
        b = self.body
        return TrueState(self.time, b.position.copy(), b.velocity.copy(), b.rotation.copy(),
                         b.rates.copy(), b.specific_force.copy())

    def mark(self) -> None:
        """Keep the present state for state(t) lookups."""
        self._history.append(self.now())
        while self._history and self._history[0].t < self.time - HISTORY_S:
            self._history.popleft()

    def state(self, t: float) -> dict:
        """The truth at t seconds since power-on: the kept sample nearest before it (now for a
        later t), in the scripted Vehicle's layout."""
        if t >= self.time or not self._history:
            return self.now().as_dict()
        chosen = self._history[0]
        for sample in self._history:
            if sample.t > t:
                break
            chosen = sample
        return chosen.as_dict()

    def range_to_ground(self, direction: np.ndarray) -> float:
        """Distance (m) from the body origin along a NED direction to the terrain (flat ground
        unless Dynamics.terrain is given); inf when it points away."""
        origin = self.body.position
        if self.dynamics.terrain is not None:
            return float(self.dynamics.terrain(origin.copy(), direction))
        if direction[2] <= 1e-6:
            return np.inf
        return float((self.body.ground_z - origin[2]) / direction[2])
