"""A ground station and a near-perfect vision companion for a simulated autopilot on a virtual
clock (virtual.VirtualLink): what a user's GCS or mission script sends (COMMAND_LONG,
SET_POSITION_TARGET_LOCAL_NED, RC_CHANNELS_OVERRIDE from MAV_GCS_SYSID's default system 255),
and ODOMETRY of the vehicle's true pose with small seeded noise at 30 Hz. For tests and the
flight benchmark; the closed-loop harness puts the real service in the companion's place."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot.virtual import VirtualLink

GCS_SYSTEM = 255
POSITION_ONLY = 0b110111111000  # SET_POSITION_TARGET type_mask: position, no yaw


class GroundStation:
    """Commands over MAVLink from system 255; results are the COMMAND_ACKs heard."""

    def __init__(self, link: VirtualLink) -> None:
        self.link = link
        self.mav = mavlink2.MAVLink(None, srcSystem=GCS_SYSTEM, srcComponent=190)

    def command(self, command: int, *params: float) -> int | None:
        """COMMAND_LONG; the result of its COMMAND_ACK (None if none came)."""
        args = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        since = self.link.now
        self.link.send(self.mav.command_long_encode(1, 1, command, 0, *args), self.mav)
        acks = [m for m in self.link.of("COMMAND_ACK", since) if m.command == command]
        return acks[-1].result if acks else None

    def mode(self, number: int) -> int | None:
        return self.command(mavlink2.MAV_CMD_DO_SET_MODE, 1, number)

    def arm(self, arm: bool = True) -> int | None:
        return self.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1 if arm else 0)

    def takeoff(self, height_m: float) -> int | None:
        return self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height_m)

    def goto(self, north: float, east: float, down: float) -> None:
        """A GUIDED position target in the EKF's local NED frame."""
        self.link.send(self.mav.set_position_target_local_ned_encode(
            0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, POSITION_ONLY, north, east, down,
            0, 0, 0, 0, 0, 0, 0, 0), self.mav)

    def sticks(self, throttle: int = 1500, roll: int = 1500, pitch: int = 1500,
               yaw: int = 1500, system: int = GCS_SYSTEM) -> None:
        """RC_CHANNELS_OVERRIDE of channels 1-4 (us), from `system`."""
        sender = self.mav if system == GCS_SYSTEM else mavlink2.MAVLink(None, srcSystem=system)
        self.link.send(sender.rc_channels_override_encode(1, 1, roll, pitch, throttle, yaw,
                                                          0, 0, 0, 0), sender)


class TruthCompanion:
    """ODOMETRY of the true body pose in a frame whose origin is `origin` (NED), with white
    position and velocity noise; `reset_counter` and `position_var` as sent."""

    def __init__(self, link: VirtualLink, seed: int = 0, position_noise_m: float = 0.01,
                 velocity_noise_ms: float = 0.02, position_var: float = 1e-4) -> None:
        self.link = link
        self.rng = np.random.default_rng(seed)
        self.noise = (position_noise_m, velocity_noise_ms)
        self.position_var = position_var
        self.origin = np.zeros(3)
        self.reset_counter = 0

    def send(self, now: float) -> None:
        state = self.link.model.vehicle.state(self.link.model.uptime(now))
        position = state["position"] - self.origin + self.rng.normal(0.0, self.noise[0], 3)
        velocity = state["rotation"].inv().apply(state["velocity"]) + \
            self.rng.normal(0.0, self.noise[1], 3)
        self.link.odometry(position, state["rotation"], velocity, self.reset_counter,
                           self.position_var, stamp_s=now)

    def fly(self, seconds: float, rate_hz: float = 30.0) -> None:
        """Advance the clock, sending at rate_hz."""
        self.link.advance(seconds, 1.0 / rate_hz, self.send)
