"""A flying simulated ArduCopter on a virtual clock with a near-perfect vision companion (the
true pose plus small seeded noise as ODOMETRY at 30 Hz) and a ground station that flies it the
way a user's GCS or mission script does (COMMAND_LONG, SET_POSITION_TARGET_LOCAL_NED,
RC_CHANNELS_OVERRIDE from system 255)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from autopilot_helpers import Companion
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from sim.autopilot import configured_options
from sim.autopilot.dynamics import Dynamics
from sim.autopilot.virtual import VirtualLink

GCS_SYSTEM = 255  # MAV_GCS_SYSID's default
GUIDED, LOITER, LAND, ALT_HOLD, STABILIZE = 4, 5, 9, 2, 0
ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
POSITION_ONLY = 0b110111111000  # SET_POSITION_TARGET type_mask: position, no yaw


@dataclass
class NoisyCompanion(Companion):
    """Companion's ODOMETRY of the truth with white position (1 cm) and velocity (2 cm/s)
    noise."""

    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(7))

    def send(self, now: float) -> None:
        state = self.link.model.vehicle.state(self.link.model.uptime(now))
        position = state["position"] - self.origin + self.rng.normal(0.0, 0.01, 3)
        velocity = state["rotation"].inv().apply(state["velocity"]) + \
            self.rng.normal(0.0, 0.02, 3)
        self.link.odometry(position, state["rotation"], velocity, self.reset_counter,
                           self.position_var, stamp_s=now)


class Flight:
    """One flight. `vision` False: the companion stays silent."""

    def __init__(self, seed: int = 0, viso_type: int = 2, position_var: float = 1e-4,
                 dynamics: Dynamics | None = None, requested: dict | None = None,
                 **changes: object) -> None:
        self.link = VirtualLink(configured_options(
            viso_type=viso_type, requested=requested or {},
            dynamics=dynamics or Dynamics(seed=seed), **changes))
        self.companion = NoisyCompanion(self.link, position_var=position_var,
                                        rng=np.random.default_rng(seed))
        self.gcs = mavlink2.MAVLink(None, srcSystem=GCS_SYSTEM, srcComponent=190)
        self.vision = True

    @property
    def model(self) -> object:
        return self.link.model

    @property
    def vehicle(self) -> object:
        return self.link.model.vehicle

    def truth(self) -> np.ndarray:
        return self.vehicle.T_ned_body[:3, 3].copy()

    def height(self) -> float:
        """True height of the body origin above where it stood at power-on."""
        return float(self.vehicle.body.contact_z - self.truth()[2])

    def fly(self, seconds: float) -> None:
        if self.vision:
            self.companion.fly(seconds)
        else:
            self.link.advance(seconds)

    def command(self, command: int, *params: float) -> int | None:
        args = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        since = self.link.now
        self.link.send(self.gcs.command_long_encode(1, 1, command, 0, *args), self.gcs)
        acks = [m for m in self.link.of("COMMAND_ACK", since) if m.command == command]
        return acks[-1].result if acks else None

    def mode(self, number: int) -> int | None:
        return self.command(mavlink2.MAV_CMD_DO_SET_MODE, 1, number)

    def goto(self, north: float, east: float, down: float) -> None:
        self.link.send(self.gcs.set_position_target_local_ned_encode(
            0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, POSITION_ONLY, north, east, down,
            0, 0, 0, 0, 0, 0, 0, 0), self.gcs)

    def sticks(self, throttle: int = 1500, roll: int = 1500, pitch: int = 1500,
               yaw: int = 1500, system: int = GCS_SYSTEM) -> None:
        sender = self.gcs if system == GCS_SYSTEM else mavlink2.MAVLink(None, srcSystem=system)
        self.link.send(sender.rc_channels_override_encode(1, 1, roll, pitch, throttle, yaw, 0, 0,
                                                          0, 0), sender)

    def take_off(self, height: float = 3.0, settle_s: float = 8.0) -> None:
        """Vision for 2 s, GUIDED, arm, NAV_TAKEOFF to `height` above home, wait."""
        self.fly(2.0)
        assert self.mode(GUIDED) == ACCEPTED
        assert self.command(ARM, 1) == ACCEPTED, self.link.texts()[-3:]
        assert self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height) == ACCEPTED
        self.fly(settle_s)


def attitude_of(msg: object) -> Rotation:
    return Rotation.from_euler("ZYX", [msg.yaw, msg.pitch, msg.roll])
