"""A flying simulated ArduCopter on a virtual clock, a near-perfect vision companion and a
ground station (sim.autopilot.ground_station), for the flight tests."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import configured_options
from sim.autopilot.dynamics import Dynamics
from sim.autopilot.ground_station import GroundStation, TruthCompanion
from sim.autopilot.virtual import VirtualLink

GUIDED, LOITER, LAND, ALT_HOLD, STABILIZE = 4, 5, 9, 2, 0
ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED


class Flight(GroundStation):
    """One flight: the ground station's commands, the companion's vision (`vision` False:
    silent), the truth."""

    def __init__(self, seed: int = 0, viso_type: int = 2, position_var: float = 1e-4,
                 dynamics: Dynamics | None = None, requested: dict | None = None,
                 **changes: object) -> None:
        super().__init__(VirtualLink(configured_options(
            viso_type=viso_type, requested=requested or {},
            dynamics=dynamics or Dynamics(seed=seed), **changes)))
        self.companion = TruthCompanion(self.link, seed=seed, position_var=position_var)
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

    def take_off(self, height: float = 3.0, settle_s: float = 8.0) -> None:
        """Vision for 2 s, GUIDED, arm, NAV_TAKEOFF to `height` above home, wait."""
        self.fly(2.0)
        assert self.mode(GUIDED) == ACCEPTED
        assert self.arm() == ACCEPTED, self.link.texts()[-3:]
        assert self.takeoff(height) == ACCEPTED
        self.fly(settle_s)
