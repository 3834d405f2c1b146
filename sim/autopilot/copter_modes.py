"""ArduCopter's flight modes as they fly with neutral sticks (ArduCopter/mode_stabilize.cpp,
mode_althold.cpp, mode_loiter.cpp, mode_guided.cpp, mode_land.cpp, takeoff.cpp), run at 50 Hz
on the CopterFlight's controllers. Each sets the motors' desired spool state, the attitude
targets and the throttle (directly, or through the position controller's vertical loop).

- STABILIZE: pilot lean angles and yaw rate, manual throttle (mid-stick = MOT_THST_HOVER).
- ALT_HOLD: pilot lean angles; climb rate from the throttle stick (0 in the dead band); takes
  off when the stick asks to climb.
- LOITER: ALT_HOLD's vertical; horizontally it brakes to its stopping point and holds it
  (AC_Loiter with no pilot input; LOIT_ACC_MAX, 2 m/s correction speed).
- GUIDED: MAV_CMD_NAV_TAKEOFF climbs straight up to the altitude above home at WPNAV_SPEED_UP
  (auto_takeoff: throttle ramps over TKOFF_SLEW_TIME until the vehicle lifts); position targets
  are flown by input_pos_xyz within WPNAV_SPEED/ACCEL and WPNAV_SPEED_UP/DN/ACCEL_Z, the heading
  following the path (WP_YAW_BEHAVIOR 2) unless a yaw is given.
- LAND: descends at LAND_SPEED below LAND_ALT_LOW (height from a healthy rangefinder, else above
  home), holding its position when it had one on entry (else level); after a failsafe it first
  pauses 4 s (set_mode_land_with_pause, LAND_WITH_DELAY_MS); disarms once landed.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from enum import Enum

import numpy as np

from sim.autopilot.control_math import sqrt_controller
from sim.autopilot.motors import Spool

LAND_PAUSE_S = 4.0  # LAND_WITH_DELAY_MS
LOITER_CORRECTION_SPEED = 2.0  # m/s, LOITER_VEL_CORRECTION_MAX


class AltHoldState(Enum):
    """Mode::get_alt_hold_state."""

    MOTOR_STOPPED = "motor stopped"
    LANDED = "landed"
    TAKEOFF = "takeoff"
    FLYING = "flying"


class FlightMode(ABC):
    """One Copter mode; `flight` is the CopterFlight it runs on."""

    number = -1
    manual_throttle = False

    def enter(self, flight: object, pause: bool = False) -> None:  # noqa: B027
        """Initialise on entry (a mode without state needs nothing)."""

    @abstractmethod
    def run(self, flight: object, dt: float) -> None:
        """One 50 Hz step."""

    def is_landing(self) -> bool:
        return False


class Stabilize(FlightMode):
    number = 0
    manual_throttle = True

    def run(self, f: object, dt: float) -> None:
        f.pos.z_active = False
        if not f.armed:
            f.motors.desired = Spool.SHUT_DOWN
        elif f.rc.throttle_zero(f.now, f.params):
            f.motors.desired = Spool.GROUND_IDLE
        else:
            f.motors.desired = Spool.THROTTLE_UNLIMITED
        if f.motors.spool in (Spool.SHUT_DOWN, Spool.GROUND_IDLE):
            f.att.relax(f.attitude)
        else:
            roll, pitch = f.rc.lean_angles(f.now, f.params, f.angle_max())
            f.att.input_euler_rate_yaw(roll, pitch, f.rc.yaw_rate(f.now, f.params))
        f.att.set_throttle(f.rc.manual_throttle(f.now, f.params), True, 0.0, f.attitude, dt)


class AltHold(FlightMode):
    number = 2

    def enter(self, f: object, pause: bool = False) -> None:
        f.set_pilot_z_limits()
        if not f.pos.z_active and not f.land.complete:
            f.pos.init_z(f.nav, f.att.throttle_in, f.hover())

    def run(self, f: object, dt: float) -> None:
        f.set_pilot_z_limits()
        climb = f.rc.climb_rate(f.now, f.params)
        roll, pitch = f.rc.lean_angles(f.now, f.params, f.angle_max())
        if self.vertical(f, climb, dt):
            f.att.input_euler_rate_yaw(roll, pitch, f.rc.yaw_rate(f.now, f.params))

    def vertical(self, f: object, climb: float, dt: float) -> bool:
        """The altitude-hold state machine; True when flying (attitude is the mode's)."""
        state = f.alt_hold_state(climb)
        if state in (AltHoldState.MOTOR_STOPPED, AltHoldState.LANDED):
            f.ground_handling(spool_up=climb > 0)
            return False
        if state is AltHoldState.TAKEOFF:
            f.motors.desired = Spool.THROTTLE_UNLIMITED
            if f.motors.spool is not Spool.THROTTLE_UNLIMITED:
                f.ground_handling(spool_up=True)
                return False
            f.start_takeoff()
        f.motors.desired = Spool.THROTTLE_UNLIMITED
        f.pos.input_climb_rate(climb, dt)
        f.pos.update_z(f.nav, dt)
        return True


class Loiter(AltHold):
    number = 5

    def enter(self, f: object, pause: bool = False) -> None:
        super().enter(f)
        self.init_target(f)

    def init_target(self, f: object) -> None:
        """AC_Loiter::init_target: brake to the stopping point from the present motion."""
        f.pos.set_xy_limits(LOITER_CORRECTION_SPEED, f.params.get("LOIT_ACC_MAX") / 100.0)
        f.pos.init_xy(f.nav, f.lean_accel())
        f.pos.hold_xy(f.pos.stopping_point_xy(f.nav))

    def run(self, f: object, dt: float) -> None:
        f.set_pilot_z_limits()
        climb = f.rc.climb_rate(f.now, f.params)
        if not self.vertical(f, climb, dt):
            self.init_target(f)
            return
        f.pos.input_vel_xy(np.zeros(2), dt)
        f.pos.update_xy(f.nav, f.angle_max(), dt)
        f.att.input_euler_rate_yaw(*f.pos.lean, f.rc.yaw_rate(f.now, f.params))


class AutoTakeoff:
    """auto_takeoff: on the ground the throttle ramps over TKOFF_SLEW_TIME until the vehicle
    accelerates up (half the vertical acceleration limit) or reaches TKOFF_THR_MAX; then the
    position controller climbs straight to the target altitude (up, above home)."""

    def __init__(self, f: object, target_alt: float) -> None:
        self.target_alt = target_alt
        self.hold = f.nav.position[:2].copy()
        self.complete = False

    def run(self, f: object, dt: float) -> None:
        f.motors.desired = Spool.THROTTLE_UNLIMITED
        if f.land.complete:
            self._lift_off(f, dt)
            return
        f.pos.input_pos_xy(self.hold, dt)
        f.pos.input_pos_z(self.target_alt, dt)
        f.pos.update_xy(f.nav, f.angle_max(), dt)
        f.pos.update_z(f.nav, dt)
        f.att.input_euler_yaw(*f.pos.lean, f.att.target[2])
        self.complete = self.complete or f.pos.z.pos[0] >= self.target_alt - 0.01

    def _lift_off(self, f: object, dt: float) -> None:
        slew = max(f.params.get("TKOFF_SLEW_TIME"), 0.25)
        throttle = min(f.att.throttle_in + dt / slew, 1.0)
        f.pos.z_active = False
        f.att.input_euler_rate_yaw(0.0, 0.0, 0.0)
        f.att.set_throttle(throttle, True, 0.0, f.attitude, dt)
        lifting = f.sensors.accel_up() >= 0.5 * f.pos.z_limits[2]
        if f.motors.spool is Spool.THROTTLE_UNLIMITED and \
                (lifting or throttle >= min(f.params.get("TKOFF_THR_MAX"), 0.9)):
            f.land.complete = False
            f.pos.init_z(f.nav, throttle, f.hover())
            f.pos.init_xy(f.nav, np.zeros(2))
            f.pos.hold_xy(self.hold)


class Guided(FlightMode):
    number = 4

    def enter(self, f: object, pause: bool = False) -> None:
        self.takeoff: AutoTakeoff | None = None
        self.target: tuple[np.ndarray, float] | None = None
        self.yaw: float | None = None
        self.start(f)

    def start(self, f: object) -> None:
        """pva_control_start: WPNAV limits, controllers from the present state."""
        p = f.params
        f.pos.set_xy_limits(p.get("WPNAV_SPEED") / 100.0, p.get("WPNAV_ACCEL") / 100.0)
        f.pos.set_z_limits(p.get("WPNAV_SPEED_DN") / 100.0, p.get("WPNAV_SPEED_UP") / 100.0,
                           p.get("WPNAV_ACCEL_Z") / 100.0)
        if not f.land.complete:
            f.pos.init_xy(f.nav, f.lean_accel())
            f.pos.init_z(f.nav, f.att.throttle_in, f.hover())
            self.target = (f.pos.stopping_point_xy(f.nav), -f.nav.position[2])

    def user_takeoff(self, f: object, alt: float) -> bool:
        """do_user_takeoff: armed, landed, and above the present altitude."""
        if not f.armed or not f.land.complete or alt <= -f.nav.position[2]:
            return False
        self.start(f)
        self.takeoff = AutoTakeoff(f, alt)
        self.target = None
        return True

    def set_destination(self, f: object, ne: np.ndarray, alt: float, yaw: float | None) -> None:
        if self.target is None and not f.land.complete:
            self.start(f)
        self.target, self.yaw, self.takeoff = (np.array(ne, float), alt), yaw, None

    def run(self, f: object, dt: float) -> None:
        if self.takeoff is not None and (self.target is None or f.land.complete):
            if not f.armed:
                f.ground_handling()
                return
            self.takeoff.run(f, dt)
            return
        if not f.armed or f.land.complete or self.target is None:
            f.ground_handling()
            return
        f.motors.desired = Spool.THROTTLE_UNLIMITED
        f.pos.input_pos_xy(self.target[0], dt)
        f.pos.input_pos_z(self.target[1], dt)
        f.pos.update_xy(f.nav, f.angle_max(), dt)
        f.pos.update_z(f.nav, dt)
        f.att.input_euler_yaw(*f.pos.lean, self._heading(f))

    def _heading(self, f: object) -> float:
        """A given yaw, else the path's heading (WP_YAW_BEHAVIOR 1-3), else hold."""
        if self.yaw is not None:
            return self.yaw
        if f.params.get("WP_YAW_BEHAVIOR") != 0 and f.pos.yaw_target is not None:
            return f.pos.yaw_target
        return f.att.target[2]


class Land(FlightMode):
    number = 9

    def enter(self, f: object, pause: bool = False) -> None:
        p = f.params
        self.control_position = f.position_ok
        self.pause_until = f.now + LAND_PAUSE_S if pause else -math.inf
        f.pos.set_z_limits(p.get("WPNAV_SPEED_DN") / 100.0, p.get("WPNAV_SPEED_UP") / 100.0,
                           p.get("WPNAV_ACCEL_Z") / 100.0)
        if not f.land.complete:
            if not f.pos.z_active:
                f.pos.init_z(f.nav, f.att.throttle_in, f.hover())
            if self.control_position:
                f.pos.set_xy_limits(p.get("WPNAV_SPEED") / 100.0, p.get("WPNAV_ACCEL") / 100.0)
                f.pos.init_xy(f.nav, f.lean_accel())
                f.pos.hold_xy(f.pos.stopping_point_xy(f.nav))

    def is_landing(self) -> bool:
        return True

    def run(self, f: object, dt: float) -> None:
        if not f.armed or f.land.complete:
            f.ground_handling()
            if f.armed and f.motors.spool is Spool.GROUND_IDLE:
                f.disarm_request = "landed"
            return
        f.motors.desired = Spool.THROTTLE_UNLIMITED
        lean = (0.0, 0.0)
        if self.control_position:
            f.pos.input_vel_xy(np.zeros(2), dt)
            f.pos.update_xy(f.nav, f.angle_max(), dt)
            lean = f.pos.lean
        rate = 0.0 if f.now < self.pause_until else self.descent_rate(f)
        f.pos.input_climb_rate(rate, dt)
        f.pos.update_z(f.nav, dt)
        f.att.input_euler_rate_yaw(*lean, 0.0)

    def descent_rate(self, f: object) -> float:
        """land_run_vertical_control: towards LAND_ALT_LOW, between the high descent speed and
        LAND_SPEED (m/s up, negative)."""
        p = f.params
        agl = f.height_above_ground()
        alt_low = max(p.get("LAND_ALT_LOW"), 100) / 100.0
        fast = (p.get("LAND_SPEED_HIGH") or p.get("WPNAV_SPEED_DN")) / 100.0
        slow = abs(p.get("LAND_SPEED")) / 100.0
        rate = sqrt_controller(alt_low - agl, p.get("PSC_POSZ_P"), f.pos.z_limits[2], 0.0)
        return min(max(rate, -max(fast, slow)), -slow)


MODE_CLASSES = {m.number: m for m in (Stabilize, AltHold, Guided, Loiter, Land)}
