"""The simulated PX4 (v1.14+): a MAVLink instance on the companion's TELEMn only when a
MAV_n_CONFIG points there, streams by that instance's MAV_n_MODE, vision through
mavlink_receiver into the EKF2 stand-in with TIMESYNC-mapped stamps, commander's modes and its
arming check for modes that need a position. Behaviour and sources: sim/autopilot/BEHAVIOUR.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from sim.autopilot.autopilot import AutopilotModel
from sim.autopilot.ekf2 import Ekf2, EvSample
from sim.autopilot.param_store import px4_from_wire, px4_wire
from sim.autopilot.params import PX4_PORTS, ParamSpec, px4_specs
from sim.autopilot.records import Event, EventKind, Severity
from sim.autopilot.sensing import Reading
from sim.autopilot.streams import PX4_KNOWN, PX4_MODE_STREAMS

CONVERGENCE_WINDOW = 500  # Timesync.hpp: samples before sync_stamp uses the offset
MAX_RTT_SAMPLE_S = 0.01  # Timesync.hpp MAX_RTT_SAMPLE: slower round trips are not used
OFFSET_ALPHA = 0.05  # smoothing of the offset estimate (Timesync's initial filter gain)
FORCE = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 that skips checks
EV_ESTIMATORS = (0, 1, 2, 3)  # MAV_ESTIMATOR_TYPE UNKNOWN, NAIVE, VISION, VIO -> EKF2
FRAMES = {mavlink2.MAV_FRAME_LOCAL_NED: "ned", 20: "frd"}  # LOCAL_FRD = 20
VEL_FRAMES = {12: "body", mavlink2.MAV_FRAME_LOCAL_NED: "ned", 20: "frd"}  # BODY_FRD = 12
FLYING_HEIGHT_M = 0.5


@dataclass(frozen=True)
class NavMode:
    """A PX4 main/sub mode (px4_custom_mode.h) and what commander requires to run it."""

    main: int
    sub: int
    name: str
    needs_position: bool
    needs_altitude: bool


NAV_MODES = [NavMode(1, 0, "Manual", False, False), NavMode(2, 0, "Altitude", False, True),
             NavMode(3, 0, "Position", True, True), NavMode(4, 2, "Takeoff", True, True),
             NavMode(4, 3, "Hold", True, True), NavMode(4, 6, "Land", True, True),
             NavMode(6, 0, "Offboard", True, True), NavMode(7, 0, "Stabilized", False, False)]


class Timesync:
    """PX4's Timesync: an offset from the replies to its own requests with a round trip under
    10 ms; until 500 of them, sync_stamp gives the arrival time instead of the mapped stamp."""

    def __init__(self) -> None:
        self.samples = 0
        self.offset = 0.0  # local - remote, seconds

    def update(self, now: float, remote_s: float, originate_s: float) -> None:
        if now - originate_s >= MAX_RTT_SAMPLE_S:
            return
        offset = (originate_s + now) / 2.0 - remote_s
        self.offset = offset if self.samples == 0 else \
            OFFSET_ALPHA * offset + (1 - OFFSET_ALPHA) * self.offset
        self.samples += 1

    @property
    def converged(self) -> bool:
        return self.samples >= CONVERGENCE_WINDOW

    def sync_stamp(self, remote_s: float, arrival_s: float) -> float:
        return remote_s + self.offset if self.converged else arrival_s


POSITION_DIAGONAL = (0, 6, 11)  # x, y, z variances in a 21-element upper triangle
ORIENTATION_DIAGONAL = (15, 18, 20)  # roll, pitch, yaw


def _variances(cov: list[float], diagonal: tuple[int, int, int]) -> np.ndarray:
    """Three diagonal entries of an upper-triangle covariance; NaN when the message says
    unknown (NaN first element)."""
    if len(cov) < 21 or np.isnan(cov[0]):
        return np.full(3, np.nan)
    return np.array([cov[i] for i in diagonal], float)


def _vpe_sample(msg: object, t: float) -> EvSample:
    """VISION_POSITION_ESTIMATE: a NED pose, variances from the covariance, quality 0."""
    attitude = Rotation.from_euler("ZYX", [msg.yaw, msg.pitch, msg.roll])
    cov = list(msg.covariance)
    nan = np.full(3, np.nan)
    return EvSample(t, np.array([msg.x, msg.y, msg.z], float),
                    _variances(cov, POSITION_DIAGONAL), attitude,
                    _variances(cov, ORIENTATION_DIAGONAL), None, nan, "ned", "ned",
                    int(msg.reset_counter), 0)


def _odometry_sample(msg: object, t: float) -> EvSample | None:
    """ODOMETRY from a VISION/VIO (or UNKNOWN/NAIVE) estimator in LOCAL_NED or LOCAL_FRD;
    NAIVE carries no variances; other estimators or frames are not EKF2's."""
    if msg.estimator_type not in EV_ESTIMATORS or msg.frame_id not in FRAMES or \
            np.linalg.norm(msg.q) < 1e-6:
        return None
    w, x, y, z = msg.q
    nan = np.full(3, np.nan)
    naive = msg.estimator_type == 1
    pose_cov, vel_cov = list(msg.pose_covariance), list(msg.velocity_covariance)
    velocity = (np.array([msg.vx, msg.vy, msg.vz], float)
                if msg.child_frame_id in VEL_FRAMES else None)
    return EvSample(t, np.array([msg.x, msg.y, msg.z], float),
                    nan if naive else _variances(pose_cov, POSITION_DIAGONAL),
                    Rotation.from_quat([x, y, z, w]),
                    nan if naive else _variances(pose_cov, ORIENTATION_DIAGONAL), velocity,
                    nan if naive else _variances(vel_cov, POSITION_DIAGONAL),
                    FRAMES[msg.frame_id], VEL_FRAMES.get(msg.child_frame_id, "body"),
                    int(msg.reset_counter), int(msg.quality))


class Px4Model(AutopilotModel):
    """PX4 on the companion's TELEMn."""

    autopilot_type = mavlink2.MAV_AUTOPILOT_PX4

    def param_specs(self, stored: dict[str, float]) -> dict[str, ParamSpec]:
        return px4_specs()

    def _instance(self) -> int | None:
        port = PX4_PORTS.get(f"TEL{self.opt.companion_serial}")
        for i in range(3):
            if self.params.get(f"MAV_{i}_CONFIG") == port:
                return i
        return None

    def port_active(self) -> bool:
        return self._instance() is not None

    def on_boot(self, now: float) -> None:
        self.ekf = Ekf2(self.params, self.record, now, self.opt.ekf_ready_after_s)
        self.timesync = Timesync()
        self.nav = NAV_MODES[0]
        self._boot_height: float | None = None
        self._last_baro = 0.0
        self._airborne = False  # the land detector's verdict since arming
        if self.opt.heartbeat_hz is not None:
            self.schedule.set("HEARTBEAT", 1.0 / self.opt.heartbeat_hz
                              if self.opt.heartbeat_hz > 0 else 0.0)
        if self.opt.timesync_hz is not None:
            self.schedule.set("TIMESYNC", 1.0 / self.opt.timesync_hz
                              if self.opt.timesync_hz > 0 else 0.0)

    def _mode_streams(self) -> dict[str, float]:
        instance = self._instance()
        if instance is None:
            return {}
        return PX4_MODE_STREAMS.get(int(self.params.get(f"MAV_{instance}_MODE")),
                                    {"HEARTBEAT": 1.0})

    def default_streams(self) -> dict[str, float]:
        return self._mode_streams()

    def known_message(self, name: str) -> bool:
        return name in PX4_KNOWN

    def default_interval(self, name: str) -> float:
        hz = self._mode_streams().get(name, 0.0)
        return 1.0 / hz if hz > 0 else 0.0

    def wire(self, value: float, kind: int) -> float:
        return px4_wire(value, kind)

    def set_param_from(self, name: str, msg: object) -> None:
        self.params.set(name, px4_from_wire(msg.param_value, self.params.specs[name].kind))

    def estimator_step(self, now: float, reading: Reading, dt: float) -> None:
        self._last_baro = reading.baro_alt
        if self._boot_height is None:
            self._boot_height = reading.baro_alt
        self.ekf.step(now, reading, dt)

    def firmware_message(self, name: str, now: float) -> object | None:
        if name == "HEARTBEAT":
            base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if self.armed:
                base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
            status = mavlink2.MAV_STATE_ACTIVE if self.armed else mavlink2.MAV_STATE_STANDBY
            custom = (self.nav.main << 16) | (self.nav.sub << 24)
            return self.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, self.autopilot_type,
                                             base, custom, status)
        if name == "LOCAL_POSITION_NED" and self.ekf.started:
            p, v = self.ekf.filter.position, self.ekf.filter.velocity
            return self.mav.local_position_ned_encode(int(self.uptime(now) * 1000), *p, *v)
        if name == "EXTENDED_SYS_STATE":
            return self.mav.extended_sys_state_encode(mavlink2.MAV_VTOL_STATE_UNDEFINED,
                                                      self._landed_state(now))
        return None

    def _landed_state(self, now: float) -> int:
        """MulticopterLandDetector, simply: landed while disarmed, and once armed until the
        vehicle moves faster than LNDMC_Z_VEL_MAX (0.5 m/s) or LNDMC_XY_VEL_MAX (1.5 m/s);
        then in the air until it is disarmed."""
        if not self.armed:
            self._airborne = False
        elif not self._airborne:
            v = self.vehicle.state(self.uptime(now))["velocity"]
            self._airborne = abs(v[2]) > 0.5 or float(np.hypot(v[0], v[1])) > 1.5
        return (mavlink2.MAV_LANDED_STATE_IN_AIR if self._airborne
                else mavlink2.MAV_LANDED_STATE_ON_GROUND)

    def timesync_reply(self, msg: object, now: float) -> None:
        """MavlinkTimesync: replies update the offset filter."""
        self.timesync_rtts.append(self.uptime(now) - msg.ts1 / 1e9)
        self.timesync.update(self.uptime(now), msg.tc1 / 1e9, msg.ts1 / 1e9)

    # --- receiving -------------------------------------------------------------------------

    def handle_firmware(self, msg: object, now: float) -> None:
        kind = msg.get_type()
        if kind in ("ODOMETRY", "VISION_POSITION_ESTIMATE"):
            sample = self._ev_sample(msg, now)
            if sample is not None:
                self.ekf.push(sample)
        elif kind == "SET_MODE" and msg.base_mode & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
            self.ack(msg, self._set_mode(main, sub, now), mavlink2.MAV_CMD_DO_SET_MODE)

    def _ev_sample(self, msg: object, now: float) -> EvSample | None:
        """mavlink_receiver's handle_message_vision_position_estimate / _odometry: the stamp
        goes through Timesync (arrival time until it has converged)."""
        uptime = self.uptime(now)
        if msg.get_type() == "VISION_POSITION_ESTIMATE":
            return _vpe_sample(msg, self.timesync.sync_stamp(msg.usec / 1e6, uptime))
        return _odometry_sample(msg, self.timesync.sync_stamp(msg.time_usec / 1e6, uptime))

    def command(self, msg: object, now: float) -> int:
        if msg.command == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm_disarm(msg, now)
        if msg.command == mavlink2.MAV_CMD_DO_SET_MODE and int(msg.param1) & 1:
            return self._set_mode(int(msg.param2), int(msg.param3), now)
        return mavlink2.MAV_RESULT_UNSUPPORTED

    # --- commander -------------------------------------------------------------------------

    def _can_run(self, mode: NavMode) -> bool:
        """Mode requirements (ModeChecks): a local position, an altitude."""
        if mode.needs_position and not self.ekf.local_position_valid():
            return False
        return not (mode.needs_altitude and not self.ekf.altitude_valid())

    def _set_mode(self, main: int, sub: int, now: float) -> int:
        """A mode that cannot run is refused (TEMPORARILY_REJECTED)."""
        mode = next((m for m in NAV_MODES if (m.main, m.sub) == (main, sub) or
                     (m.main == main and main != 4)), None)
        if mode is None:
            return mavlink2.MAV_RESULT_UNSUPPORTED
        if not self._can_run(mode):
            self.record.events.append(Event(now, EventKind.MODE_REFUSED, mode.name))
            return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        self.nav = mode
        self.record.events.append(Event(now, EventKind.MODE, mode.name))
        return mavlink2.MAV_RESULT_ACCEPTED

    def _arm_disarm(self, msg: object, now: float) -> int:
        if msg.param1 == 0:
            flying = self._boot_height is not None and \
                self._last_baro - self._boot_height > FLYING_HEIGHT_M
            if self.armed and flying and msg.param2 != FORCE:
                return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
            if self.armed:
                self.record.events.append(Event(now, EventKind.DISARMED))
            self.armed = False
            return mavlink2.MAV_RESULT_ACCEPTED
        return self.arm(now, checks=msg.param2 != FORCE)

    def arm(self, now: float, checks: bool = True) -> int:
        """Commander::arm: refused while the current mode cannot run."""
        if self.armed:
            return mavlink2.MAV_RESULT_ACCEPTED
        if checks and not self._can_run(self.nav):
            self.say(Severity.CRITICAL, "Arming denied: Resolve system health failures first",
                     now)
            self.record.events.append(Event(now, EventKind.ARMING_REFUSED, self.nav.name))
            return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        self.armed = True
        self.record.events.append(Event(now, EventKind.ARMED, self.nav.name))
        return mavlink2.MAV_RESULT_ACCEPTED

    def set_mode_named(self, name: str, now: float) -> bool:
        mode = next((m for m in NAV_MODES if m.name.lower() == name.lower()), None)
        return mode is not None and \
            self._set_mode(mode.main, mode.sub, now) == mavlink2.MAV_RESULT_ACCEPTED
