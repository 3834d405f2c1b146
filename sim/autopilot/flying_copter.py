"""What the simulated ArduCopter adds when its vehicle flies (SimOptions.dynamics): the flight
controller's sensors, its 400 Hz loop driving the motors, the flight modes steering on EKF3's
estimate, and the MAVLink a ground station flies it with:

- MAV_CMD_NAV_TAKEOFF (param7, or z of COMMAND_INT: metres above home) in GUIDED, armed and
  landed (Copter::Mode::do_user_takeoff; GCS_MAVLINK_Copter handle_MAV_CMD_NAV_TAKEOFF);
- SET_POSITION_TARGET_LOCAL_NED in GUIDED with a position (frames LOCAL_NED, LOCAL_OFFSET_NED,
  BODY_NED, BODY_OFFSET_NED; velocity/acceleration targets are not modelled and ignored), yaw
  when the type mask gives one (GCS_MAVLINK_Copter handle_message_set_position_target_local_ned;
  no COMMAND_ACK, as there);
- RC_CHANNELS_OVERRIDE from the ground station's system id (rc_input.py).
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot.copter_flight import CopterFlight
from sim.autopilot.copter_modes import Guided
from sim.autopilot.dynamics import FlyingVehicle
from sim.autopilot.flight_sensors import FlightSensors
from sim.autopilot.param_store import ParamStore
from sim.autopilot.sensing import Reading

FAST_LOOP_HZ = 400.0
POS_IGNORE, VEL_IGNORE, ACC_IGNORE = 0b111, 0b111000, 0b111000000
YAW_IGNORE = 1 << 10
LOCAL_FRAMES = {mavlink2.MAV_FRAME_LOCAL_NED: (False, False),
                mavlink2.MAV_FRAME_LOCAL_OFFSET_NED: (True, False),
                mavlink2.MAV_FRAME_BODY_NED: (False, True),
                mavlink2.MAV_FRAME_BODY_OFFSET_NED: (True, True)}  # (offset, body-turned)


class FlyingCopter:
    """The flight side of one ArduCopter model; rebuilt (controllers reset) at each boot, the
    sensors kept (they are hardware) and the barometer calibrated again."""

    def __init__(self, params: ParamStore, vehicle: FlyingVehicle, seed: int,
                 sensors: FlightSensors | None = None) -> None:
        self.vehicle = vehicle
        self.sensors = sensors or FlightSensors(vehicle, params, seed)
        self.sensors.calibrate_baro()
        self.flight = CopterFlight(params, self.sensors)
        self.params = params
        self._loops = 0  # fast loops already run of the step in progress

    def fly_ahead(self, elapsed: float) -> None:
        """Run the fast loops of the step in progress that are due `elapsed` s into it, so the
        vehicle is where it is now, not where it was at the last 50 Hz step (a camera frame
        taken between steps saw it up to 20 ms early)."""
        self._run_loops(int(elapsed * FAST_LOOP_HZ + 1e-9), 1.0 / FAST_LOOP_HZ)

    def fly(self, dt: float) -> Reading:
        """Run the rest of the 400 Hz loop for the step of dt (sensors, control, motors,
        physics); the estimator's reading for the step."""
        steps = self._steps(dt)
        self._run_loops(steps, dt / steps)
        self._loops = 0
        self.vehicle.mark()
        return self.sensors.reading()

    @staticmethod
    def _steps(dt: float) -> int:
        return max(round(dt * FAST_LOOP_HZ), 1)

    def _run_loops(self, until: int, dt: float) -> None:
        while self._loops < until:
            self._loops += 1
            self.sensors.tick()
            self.vehicle.advance(dt, self.flight.fast(dt))

    def after_estimator(self, ekf: object, position_ok: bool, now: float, dt: float) -> None:
        """The 50 Hz flight step on the estimate just made; EKF3 learns the ground-effect
        flags for its next step."""
        self.flight.update(ekf.estimate(), position_ok, now, dt)
        ekf.takeoff_expected = self.flight.takeoff_expected
        ekf.touchdown_expected = self.flight.touchdown_expected

    def takeoff(self, msg: object) -> bool:
        """MAV_CMD_NAV_TAKEOFF: only GUIDED flies it here (LOITER/ALT_HOLD's user takeoff is
        not modelled)."""
        alt = msg.z if msg.get_type() == "COMMAND_INT" else msg.param7
        mode = self.flight.mode
        return isinstance(mode, Guided) and math.isfinite(alt) and \
            mode.user_takeoff(self.flight, float(alt))

    def position_target(self, msg: object) -> None:
        """SET_POSITION_TARGET_LOCAL_NED in GUIDED (position targets)."""
        mode = self.flight.mode
        frame = LOCAL_FRAMES.get(msg.coordinate_frame)
        if not isinstance(mode, Guided) or frame is None or msg.type_mask & POS_IGNORE:
            return
        nav = self.flight.nav
        target = np.array([msg.x, msg.y, msg.z], float)
        offset, body = frame
        if body:
            c, s = math.cos(nav.yaw), math.sin(nav.yaw)
            target[:2] = [c * target[0] - s * target[1], s * target[0] + c * target[1]]
        if offset:
            target = target + nav.position
        yaw = None if msg.type_mask & YAW_IGNORE else float(msg.yaw)
        mode.set_destination(self.flight, target[:2], -float(target[2]), yaw)

    def rc_override(self, msg: object, now: float, gcs_sysid: int) -> None:
        if msg.get_srcSystem() == gcs_sysid:
            self.flight.rc.override([msg.chan1_raw, msg.chan2_raw, msg.chan3_raw,
                                     msg.chan4_raw], now)

    def reported(self) -> dict:
        return self.sensors.reported()
