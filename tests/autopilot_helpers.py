"""Flights and scripted vision companions for the simulated-autopilot tests."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from sim.autopilot.virtual import VirtualLink
from sim.trajectory import Trajectory


def takeoff(height: float = 3.4, ground_s: float = 2.0, climb_s: float = 2.0,
            total_s: float = 60.0, yaw_deg: float = 30.0, north_speed: float = 0.0
            ) -> Trajectory:
    """On the ground (NED z = 0) for ground_s, a smooth climb to `height`, then a hover (or
    flying north at `north_speed` from the top of the climb)."""
    t = np.arange(0.0, total_s, 0.005)
    s = np.clip((t - ground_s) / climb_s, 0.0, 1.0)
    z = -height * (3 * s**2 - 2 * s**3)
    north = north_speed * np.clip(t - ground_s - climb_s, 0.0, None)
    positions = np.stack([north, 0 * t, z], 1)
    quat = Rotation.from_euler("z", np.full((len(t), 1), yaw_deg), degrees=True).as_quat()
    return Trajectory(t, positions, quat)


@dataclass
class Companion:
    """A vision companion that sends ODOMETRY of the true pose of a camera `lever` (body FRD)
    from the vehicle's centre, in a frame whose origin is `origin` (NED, where the vision map
    started) and turned by `yaw_offset_deg` about down; `reset_counter` is what it puts in
    every message."""

    link: VirtualLink
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_offset_deg: float = 0.0
    reset_counter: int = 0
    position_var: float = 0.01
    lever: np.ndarray = field(default_factory=lambda: np.zeros(3))  # camera in body FRD

    def send(self, now: float) -> None:
        """The pose at `now` (which may be earlier than the link's clock: a late message)."""
        state = self.link.model.vehicle.state(self.link.model.uptime(now))
        turn = Rotation.from_euler("z", self.yaw_offset_deg, degrees=True)
        camera = state["position"] + state["rotation"].apply(self.lever)
        position = turn.apply(camera - self.origin)
        attitude = turn * state["rotation"]
        velocity_body = state["rotation"].inv().apply(state["velocity"])
        self.link.odometry(position, attitude, velocity_body, self.reset_counter,
                           self.position_var, stamp_s=now)  # stamped at capture

    def fly(self, seconds: float, rate_hz: float = 30.0) -> None:
        self.link.advance(seconds, 1.0 / rate_hz, self.send)


def height_jump(link: VirtualLink, t_from: float) -> float:
    """The largest change of the autopilot's height estimate between consecutive records
    (10 Hz) after t_from, minus the vehicle's own climb in that time."""
    record = link.model.record
    samples = [s for s in record.estimates if s.t >= t_from]
    worst = 0.0
    vehicle = link.model.vehicle
    for a, b in itertools.pairwise(samples):
        truth = (vehicle.state(link.model.uptime(b.t))["position"][2]
                 - vehicle.state(link.model.uptime(a.t))["position"][2])
        worst = max(worst, abs((b.position[2] - a.position[2]) - truth))
    return worst
