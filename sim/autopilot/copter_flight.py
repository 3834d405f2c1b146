"""ArduCopter's flight control on the simulated vehicle: the 400 Hz loop (attitude and rate
control, the vertical acceleration loop, motor mixing) and the 50 Hz work around the flight
modes (copter_modes.py): the land detector, the throttle-versus-attitude mix, hover-throttle
learning, the ground-effect flags for EKF3 and the automatic disarm. Sources:

- land_detector.cpp update_land_detector: landed after 1 s (LAND_DETECTOR_TRIGGER_SEC) of the
  motors at their lower limit with the minimum throttle mix, the 1 Hz filtered acceleration
  under 1 m/s^2, the vertical speed under 1 m/s and a healthy rangefinder (if any) under 2 m;
  "maybe landed" after 0.2 s; a manual throttle above half the hover throttle takes off;
- Copter::update_throttle_mix and AC_AttitudeControl_Multi::update_throttle_rpy_mix (the mix
  slews down at 0.5/s, up at 1/s);
- Copter::update_throttle_hover (MOT_HOVER_LEARN 2, 10 s time constant, level and not climbing);
- Copter::update_ground_effect_detector (GND_EFFECT_COMP): takeoff expected from arming until
  5 s or 0.5 m of climb, touchdown expected in a slow descent with little horizontal speed;
- motors.cpp auto_disarm_check: DISARM_DELAY seconds landed with the throttle stick down.
"""

from __future__ import annotations

import math

import numpy as np

from sim.autopilot.attitude_control import AttitudeControl, euler_to_matrix, rotation_vector
from sim.autopilot.control_math import lowpass_alpha
from sim.autopilot.copter_modes import MODE_CLASSES, AltHoldState, FlightMode
from sim.autopilot.flight_sensors import FlightSensors
from sim.autopilot.motors import Motors, Spool
from sim.autopilot.param_store import ParamStore
from sim.autopilot.position_control import NavEstimate, PositionControl, lean_to_accel
from sim.autopilot.rc_input import RcInput

THROTTLE_CUTOFF_HZ = 2.0  # POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ
HOVER_LEARN_TC_S = 10.0  # AP_MOTORS_THST_HOVER_TC
LAND_TRIGGER_S = 1.0
LARGE_ANGLE = math.radians(15.0)  # LAND_CHECK_LARGE_ANGLE_CD
ACCEL_MOVING = 3.0  # LAND_CHECK_ACCEL_MOVING, m/s^2
FLT_EPSILON = 1.1920929e-07  # AP_Math is_zero(): a shaped climb rate decays to residue, not 0


class LandDetector:
    """ap.land_complete (land_complete_maybe not modelled: nothing here reads it)."""

    def __init__(self) -> None:
        self.complete = True
        self.settled_s = 0.0
        self.accel = np.zeros(3)


class CopterFlight:
    """The flight controller of one flying ArduCopter."""

    def __init__(self, params: ParamStore, sensors: FlightSensors) -> None:
        self.params = params
        self.sensors = sensors
        self.motors = Motors()
        self.att = AttitudeControl(params)
        self.pos = PositionControl(params)
        self.rc = RcInput()
        self.land = LandDetector()
        self.armed = False
        self.now = 0.0
        self.nav = NavEstimate(np.zeros(3), np.zeros(3), 0.0, np.zeros(2), 0.0)
        self.position_ok = False
        self.mode: FlightMode = MODE_CLASSES[0]()
        self.throttle_mix = params.get("ATC_THR_MIX_MIN")
        self.takeoff_expected = False
        self.touchdown_expected = False
        self.disarm_request: str | None = None
        self._takeoff_start = (0.0, 0.0)
        self._disarm_timer = 0.0

    @property
    def attitude(self) -> np.ndarray:
        return self.sensors.attitude

    # --- helpers the modes use --------------------------------------------------------------

    def hover(self) -> float:
        return self.params.get("MOT_THST_HOVER")

    def angle_max(self) -> float:
        limit = self.params.get("PSC_ANGLE_MAX")
        return math.radians(limit) if limit > 0 else self.att.angle_max()

    def lean_accel(self) -> np.ndarray:
        return lean_to_accel(self.att.target[0], self.att.target[1], self.nav.yaw)

    def set_pilot_z_limits(self) -> None:
        p = self.params
        up = p.get("PILOT_SPEED_UP") / 100.0
        self.pos.set_z_limits((p.get("PILOT_SPEED_DN") / 100.0) or up, up,
                              p.get("PILOT_ACCEL_Z") / 100.0)

    def height_above_ground(self) -> float:
        """A healthy rangefinder's reading, else the altitude above home."""
        if self.sensors.rangefinder_healthy():
            return self.sensors.rangefinder.distance_m
        return -self.nav.position[2]

    def alt_hold_state(self, climb: float) -> AltHoldState:
        if not self.armed:
            return AltHoldState.MOTOR_STOPPED
        if self.land.complete:
            return AltHoldState.TAKEOFF if climb > 0 else AltHoldState.LANDED
        return AltHoldState.FLYING

    def ground_handling(self, spool_up: bool = False) -> None:
        """make_safe_ground_handling: idle (or spooling up to take off), controllers relaxed."""
        if not self.armed:
            self.motors.desired = Spool.SHUT_DOWN
        else:
            self.motors.desired = Spool.THROTTLE_UNLIMITED if spool_up else Spool.GROUND_IDLE
        self.att.relax(self.attitude)
        self.att.throttle_in = self.att.throttle_out = 0.0
        self.pos.z_active = False

    def start_takeoff(self) -> None:
        """_TakeOff::start: no longer landed, vertical control from here without descent."""
        self.land.complete = False
        self.pos.init_z(self.nav, self.att.throttle_in, self.hover())
        self.pos.z.vel = np.maximum(self.pos.z.vel, 0.0)

    # --- the model's calls ------------------------------------------------------------------

    def set_mode(self, number: int, pause: bool = False) -> None:
        self.mode = MODE_CLASSES[number]()
        self.mode.enter(self, pause)

    def arm(self) -> None:
        self.armed = True
        self.land.complete = True
        self.disarm_request = None
        self._takeoff_start = (self.now, -self.nav.position[2])

    def disarm(self) -> None:
        self.armed = False
        self.disarm_request = None

    def fast(self, dt: float) -> np.ndarray:
        """One 400 Hz loop: the motor commands."""
        self.motors.update_spool(self.armed, dt, self.params.get("MOT_SPOOL_TIME"))
        if self.pos.z_active:
            limit = self.motors.limit
            throttle = self.pos.throttle(self.sensors.accel_up(), self.hover(), dt,
                                         limit.throttle_lower or limit.throttle_upper)
            self.att.set_throttle(throttle, True, THROTTLE_CUTOFF_HZ, self.attitude, dt)
        out = self.att.run(self.attitude, self.sensors.gyro, dt, self.motors.limit)
        return self.motors.output(*out, self.att.throttle_out, self.params)

    def update(self, nav: NavEstimate, position_ok: bool, now: float, dt: float) -> None:
        """The 50 Hz step: land detector, the mode, and Copter's housekeeping."""
        self.now, self.nav, self.position_ok = now, nav, position_ok
        self.att.refresh()
        self._land_detector(dt)
        self.mode.run(self, dt)
        self._throttle_mix(dt)
        self._learn_hover(dt)
        self._ground_effect()
        self._auto_disarm(dt)

    # --- housekeeping -------------------------------------------------------------------------

    def _land_detector(self, dt: float) -> None:
        land = self.land
        land.accel += (self.sensors.accel_ned() - land.accel) * lowpass_alpha(1.0, dt)
        if not self.armed:
            land.complete, land.settled_s = True, 0.0
        elif land.complete:
            if self.mode.manual_throttle and self.motors.spool is Spool.THROTTLE_UNLIMITED and \
                    self.att.throttle_out > 0.5 * self.hover():
                land.complete = False
        else:
            settled = (self.motors.limit.throttle_lower and self._mix_is_min()
                       and float(np.linalg.norm(land.accel)) <= 1.0
                       and abs(self.nav.velocity[2]) < 1.0
                       and (not self.sensors.rangefinder_healthy()
                            or self.sensors.rangefinder.distance_m < 2.0))
            land.settled_s = land.settled_s + dt if settled else 0.0
            land.complete = land.settled_s >= LAND_TRIGGER_S

    def _mix_is_min(self) -> bool:
        return self.throttle_mix < 1.25 * self.params.get("ATC_THR_MIX_MIN")

    def desired_climb(self) -> float:
        """The position controller's desired climb rate (m/s), zero within float residue: with
        neutral sticks the jerk-limited target decays towards 0 without reaching it, and a
        residue of -1e-12 m/s read as a descent demand flagged touchdown in every LOITER hold
        (the baro then barely fused) and stopped hover learning."""
        vel = float(self.pos.z.vel[0])
        return 0.0 if abs(vel) < FLT_EPSILON else vel

    def _throttle_mix(self, dt: float) -> None:
        low = self.params.get("ATC_THR_MIX_MIN")
        if not self.armed or self.land.complete:
            desired = low
        elif self.mode.manual_throttle:
            desired = low if self.rc.throttle_zero(self.now, self.params) else 0.5
        else:
            error = float(np.linalg.norm(rotation_vector(
                self.attitude.T @ euler_to_matrix(*self.att.target))))
            large_request = math.hypot(*self.att.target[:2]) > LARGE_ANGLE
            moving = float(np.linalg.norm(self.land.accel)) > ACCEL_MOVING
            demanded_descent = self.desired_climb() < 0.0
            aggressive = (large_request and not self.mode.is_landing()) or \
                error > 2 * LARGE_ANGLE or moving or not demanded_descent
            desired = 0.5 if aggressive else low
        if desired < self.throttle_mix:
            self.throttle_mix -= min(0.5 * dt, self.throttle_mix - desired)
        else:
            self.throttle_mix += min(1.0 * dt, desired - self.throttle_mix)

    def _learn_hover(self, dt: float) -> None:
        if self.params.get("MOT_HOVER_LEARN") == 0 or not self.armed or self.land.complete \
                or self.mode.manual_throttle or self.desired_climb() != 0.0:
            return
        roll, pitch, _ = self.att.target
        if self.att.throttle_out > 0 and abs(self.nav.velocity[2]) < 0.6 and \
                abs(roll) < math.radians(5) and abs(pitch) < math.radians(5):
            hover = self.hover() + dt / (dt + HOVER_LEARN_TC_S) * \
                (self.att.throttle_out - self.hover())
            self.params.set("MOT_THST_HOVER", min(max(hover, 0.125), 0.6875))

    def _ground_effect(self) -> None:
        if self.params.get("GND_EFFECT_COMP") == 0:
            self.takeoff_expected = self.touchdown_expected = False
            return
        alt = -self.nav.position[2]
        if self.armed and self.land.complete:
            self.takeoff_expected = True
            self._takeoff_start = (self.now, alt)
        elif self.takeoff_expected and (self.now - self._takeoff_start[0] > 5.0
                                        or alt - self._takeoff_start[1] > 0.5):
            self.takeoff_expected = False
        slow_horizontal = float(np.linalg.norm(self.pos.xy.vel)) <= 1.25 or \
            float(np.linalg.norm(self.nav.velocity[:2])) <= 1.25
        descending = self.pos.z_active and self.desired_climb() < 0.0
        slow_descent = descending and (self.desired_climb() >= -1.0
                                       or abs(self.nav.velocity[2]) <= 0.6)
        self.touchdown_expected = self.armed and slow_horizontal and slow_descent

    def _auto_disarm(self, dt: float) -> None:
        delay = self.params.get("DISARM_DELAY")
        low = self.rc.throttle_zero(self.now, self.params)
        if not self.armed or delay <= 0 or not (low and self.land.complete):
            self._disarm_timer = 0.0
            return
        self._disarm_timer += dt
        if self._disarm_timer >= delay:
            self.disarm_request = "disarm delay"
