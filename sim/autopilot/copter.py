"""The simulated ArduCopter (upstream master of mid-2025, or 4.5's parameter names): its MAVLink
channel on the companion's SERIALn, stream groups, vision through AP_VisualOdom into the EKF3
stand-in, flight modes, pre-arm checks and the EKF failsafe. Behaviour and sources:
sim/autopilot/BEHAVIOUR.md."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot.autopilot import AutopilotModel
from sim.autopilot.ekf3 import Ekf3
from sim.autopilot.flight_params import flight_specs
from sim.autopilot.flying_copter import FlyingCopter
from sim.autopilot.gcs_vision import JitterCorrection, vision_samples
from sim.autopilot.param_store import ardupilot_cast
from sim.autopilot.params import (
    STREAM_GROUPS,
    ParamSpec,
    Release,
    ardupilot_specs,
    mavlink_channel,
    stream_rate_name,
)
from sim.autopilot.records import Event, EventKind, Severity
from sim.autopilot.sensing import Reading
from sim.autopilot.streams import (
    AP_DATA_STREAMS,
    AP_DEFAULT_INTERVAL,
    AP_GROUP_MESSAGES,
    AP_KNOWN,
    VISION_MESSAGES,
    Schedule,
    ardupilot_group_rates,
)
from sim.autopilot.vehicle import SENSOR_MESSAGES, sensor_message
from sim.autopilot.visual_odom import Ahrs, VisualOdom

ARMING_CHECK_ALL = 1
ARMING_CHECK_VISION = 1 << 18
FORCE_ARM = 2989  # magic_force_arm_value
FORCE_ARM_DISARM = 21196  # magic_force_arm_disarm_value
NO_STREAM_OVERRIDE = 1 << 2  # MAVn_OPTIONS bit 2, "Ignore Streamrate"
EKF_CHECK_PERIOD_S = 0.1
EKF_CHECK_ITERATIONS = 10  # ekf_check.cpp EKF_CHECK_ITERATIONS_MAX: 1 s at 10 Hz
FLYING_HEIGHT_M = 0.5  # above the boot height: in the air (no disarm, no height datum reset)


@dataclass(frozen=True)
class Mode:
    """A Copter flight mode: custom_mode number, name, and what it needs (mode.h)."""

    number: int
    name: str
    requires_position: bool
    manual_throttle: bool
    allows_arming: bool = True


MODES = {m.number: m for m in (
    Mode(0, "STABILIZE", False, True), Mode(2, "ALT_HOLD", False, False),
    Mode(4, "GUIDED", True, False), Mode(5, "LOITER", True, False),
    Mode(9, "LAND", False, False, allows_arming=False))}
POSITION_MODES = (4, 5)  # modes whose base_mode has MAV_MODE_FLAG_GUIDED_ENABLED here


class ArduCopterModel(AutopilotModel):
    """ArduCopter on the companion's SERIALn."""

    MODES = MODES
    autopilot_type = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    dialect = ardupilotmega

    def param_specs(self, stored: dict[str, float]) -> dict[str, ParamSpec]:
        return {**ardupilot_specs(self.opt.release, stored), **flight_specs()}

    def port_active(self) -> bool:
        return self._channel is not None

    def on_boot(self, now: float) -> None:
        booted = {n: self.params.get(n) for n in self.params.names()}
        self._channel = mavlink_channel(booted, self.opt.companion_serial)
        self.ahrs = Ahrs()
        self.ekf = Ekf3(self.params, self.say, self.record, now, self.opt.ekf_ready_after_s)
        self.visual_odom = VisualOdom(self.params, self.ahrs, self.say)
        self.jitter = JitterCorrection()
        self.mode = MODES[0]
        self.failsafe_ekf = False
        self._ekf_check = (now, 0)
        self._boot_height = None
        self._last_timesync = now
        self._sent_ts1 = -1
        self.flying: FlyingCopter | None = None
        if self.flies:
            sensors = getattr(self, "_sensors", None)  # hardware: kept across reboots
            self.flying = FlyingCopter(self.params, self.vehicle, self.opt.dynamics.seed, sensors)
            self._sensors = self.flying.sensors
        if self.opt.heartbeat_hz is None or self.opt.heartbeat_hz > 0:
            self.schedule.set("HEARTBEAT", 1.0 / (self.opt.heartbeat_hz or 1.0))
        if self.opt.timesync_hz:
            self.schedule.set("TIMESYNC", 1.0 / self.opt.timesync_hz)

    def default_streams(self) -> dict[str, float]:
        if self._channel_now() is None:
            return {}
        schedule = Schedule()
        ardupilot_group_rates(schedule, {g: self._group_rate(g) for g in STREAM_GROUPS})
        return {name: schedule.rate_hz(name) for name in schedule.intervals}

    def _channel_now(self) -> int | None:
        booted = {n: self.params.get(n) for n in self.params.names()}
        return mavlink_channel(booted, self.opt.companion_serial)

    def _group_rate(self, group: str) -> float:
        return self.params.get(stream_rate_name(self.opt.release, self._channel_now(), group))

    def known_message(self, name: str) -> bool:
        return name in AP_KNOWN

    def default_interval(self, name: str) -> float:
        """get_default_interval_for_ap_message: the rate of a stream group holding it."""
        for group, members in AP_GROUP_MESSAGES.items():
            hz = self._group_rate(group)
            if name in members and hz > 0:
                return 1.0 / hz
        return AP_DEFAULT_INTERVAL.get(name, 0.0)

    def set_param_from(self, name: str, msg: object) -> None:
        self.params.set(name, ardupilot_cast(msg.param_value, self.params.specs[name].kind))

    def sends_mavlink1(self) -> bool:
        return self.params.get(f"SERIAL{self.opt.companion_serial}_PROTOCOL") == 1

    def set_mode_named(self, name: str, now: float) -> bool:
        mode = next((m for m in MODES.values() if m.name == name.upper()), None)
        return mode is not None and self.set_mode(mode, now)

    def read_index(self, name: str) -> int:
        return 65535  # param_io_timer echoes the requested index, -1, as the uint16 field

    def accept_origin(self, now: float) -> bool:
        """set_ekf_origin: refused once an origin is set or while the EKF has not started."""
        return self.origin is None and self.ekf.started

    def set_origin(self, now: float, kind: str, lat: int, lon: int, alt_mm: int) -> bool:
        ok = super().set_origin(now, kind, lat, lon, alt_mm)
        if ok:
            self.say(Severity.INFO, "EKF3 IMU0 origin set", now)
        return ok

    # --- the step --------------------------------------------------------------------------

    def step(self, now: float) -> None:
        super().step(now)
        if self.down:
            return
        if self.opt.timesync_hz is None and now - self._last_timesync > 10.0:
            # GCS_MAVLINK::update_receive: a TIMESYNC every 10 s for the TSYN log
            self._last_timesync = now
            self.send(self.timesync_request(now))

    def timesync_request(self, now: float) -> object:
        """ts1 is micros*1000 + our system id (timesync_timestamp_ns)."""
        self._sent_ts1 = round(self.uptime(now) * 1e6) * 1000 + self.opt.system_id
        return self.mav.timesync_encode(0, self._sent_ts1)

    def timesync_reply(self, msg: object, now: float) -> None:
        """handle_timesync: only a reply to the last request counts (its round trip goes to
        the TSYN log; here to timesync_rtts)."""
        if msg.ts1 == self._sent_ts1:
            self.timesync_rtts.append(self.uptime(now) - msg.ts1 / 1e9)

    def estimator_step(self, now: float, reading: Reading, dt: float) -> None:
        self.ahrs.attitude = reading.attitude
        self.ahrs.yaw_initialised = self.ekf.yaw_aligned
        self.ahrs.using_extnav_for_yaw = self.ekf.using_extnav_for_yaw
        if self._boot_height is None:
            self._boot_height = reading.baro_alt
        self._last_baro = reading.baro_alt
        self.ekf.step(now, reading, dt)
        if now - self._ekf_check[0] >= EKF_CHECK_PERIOD_S:
            self._run_ekf_check(now)
        if self.flying is not None:
            self.flying.after_estimator(self.ekf, self.position_ok(now), now, dt)
            if self.flying.flight.disarm_request is not None:
                self._disarm(now, self.flying.flight.disarm_request)

    def fly_ahead(self, elapsed: float) -> None:
        self.flying.fly_ahead(elapsed)

    def fly(self, dt: float) -> Reading:
        return self.flying.fly(dt)

    def stream_message(self, name: str, now: float) -> object | None:
        """A flying vehicle's sensor streams carry its flight controller's readings."""
        if self.flying is None or name not in SENSOR_MESSAGES:
            return super().stream_message(name, now)
        state = self.flying.reported()
        if name == "DISTANCE_SENSOR" and "range" not in state:
            return None  # no rangefinder (RNGFND1_TYPE 0 or none fitted)
        uptime = self.uptime(now)
        return sensor_message(self.mav, name, uptime, int(uptime * 1000), _Reported(state))

    def firmware_message(self, name: str, now: float) -> object | None:
        if name == "HEARTBEAT":
            return self._heartbeat()
        if name == "LOCAL_POSITION_NED" and self.ekf.started:
            p, v = self.ekf.filter.position, self.ekf.filter.velocity
            return self.mav.local_position_ned_encode(int(self.uptime(now) * 1000), *p, *v)
        if name == "EKF_STATUS_REPORT" and self.ekf.started:
            return self._ekf_status(now)
        return None

    def _heartbeat(self) -> object:
        """GCS_MAVLINK_Copter base_mode and vehicle_system_status."""
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | \
            mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.mode.number in POSITION_MODES:
            base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        if not self.ekf.started:
            status = mavlink2.MAV_STATE_BOOT
        elif self.failsafe_ekf:
            status = mavlink2.MAV_STATE_CRITICAL
        elif self.flying is not None:  # STANDBY while ap.land_complete, armed or not
            status = mavlink2.MAV_STATE_ACTIVE if self._in_the_air() else mavlink2.MAV_STATE_STANDBY
        else:
            status = mavlink2.MAV_STATE_ACTIVE if self.armed else mavlink2.MAV_STATE_STANDBY
        return self.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, self.autopilot_type,
                                         base, self.mode.number, status)

    def _ekf_status(self, now: float) -> object:
        """EKF_STATUS_REPORT: flags from the filter status, variances as sqrt(test ratio)."""
        flags = self.ekf.status(now)
        bits = {"attitude": 1, "horiz_vel": 2, "vert_vel": 4, "horiz_pos_rel": 8 | 256,
                "horiz_pos_abs": 16 | 512, "vert_pos": 32, "const_pos_mode": 128}
        value = sum(bit for name, bit in bits.items() if flags[name])
        if not flags["initialized"]:
            value |= 1024
        r = self.ekf.ratios
        return self.mav.ekf_status_report_encode(value, np.sqrt(r["vel"]), np.sqrt(r["pos"]),
                                                 np.sqrt(r["hgt"]), 0.0, 0.0)

    # --- receiving -------------------------------------------------------------------------

    def handle_firmware(self, msg: object, now: float) -> None:
        kind = msg.get_type()
        if kind in VISION_MESSAGES:
            self._vision(msg, now)
        elif kind == "REQUEST_DATA_STREAM":
            self._request_data_stream(msg)
        elif kind == "SET_MODE":
            custom = msg.custom_mode if msg.base_mode & 1 else None
            self.ack(msg, self._set_mode_common(custom, now), mavlink2.MAVLINK_MSG_ID_SET_MODE)
        elif self.flying is not None and kind == "SET_POSITION_TARGET_LOCAL_NED" and \
                msg.target_system == self.opt.system_id:
            self.flying.position_target(msg)
        elif self.flying is not None and kind == "RC_CHANNELS_OVERRIDE" and \
                msg.target_system == self.opt.system_id:
            self.flying.rc_override(msg, now, int(self.params.get(self._gcs_sysid_name())))

    def _vision(self, msg: object, now: float) -> None:
        pose, velocity = vision_samples(msg, now, self.jitter)
        if pose is not None:
            out = self.visual_odom.handle_pose(pose, now)
            if out is not None:
                self.ekf.write_ext_nav(out)
            elif self.visual_odom.ignoring():
                self.record.events.append(Event(now, EventKind.VISION_IGNORED))
        if velocity is not None:
            out = self.visual_odom.handle_velocity(velocity, now)
            if out is not None:
                self.ekf.write_ext_nav_vel(out)

    def _request_data_stream(self, msg: object) -> None:
        """A group's rate in RAM (not saved: Copter's persist_streamrates() is false), applied
        now; ignored with MAVn_OPTIONS bit 2."""
        channel = self._channel_now()
        if self.opt.release is Release.MASTER_2025 and \
                int(self.params.get(f"MAV{channel + 1}_OPTIONS")) & NO_STREAM_OVERRIDE:
            return
        if msg.start_stop not in (0, 1):
            return
        hz = float(msg.req_message_rate) if msg.start_stop == 1 else 0.0
        groups = ([g for g in STREAM_GROUPS if g != "PARAMS"] if msg.req_stream_id == 0
                  else [AP_DATA_STREAMS[msg.req_stream_id]]
                  if msg.req_stream_id in AP_DATA_STREAMS else [])
        for group in groups:
            self.params.set(stream_rate_name(self.opt.release, channel, group), hz,
                            persist=False)
        ardupilot_group_rates(self.schedule, dict.fromkeys(groups, hz))

    def command(self, msg: object, now: float) -> int:
        if msg.command == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm_disarm(msg, now)
        if msg.command == mavlink2.MAV_CMD_DO_SET_MODE:
            custom = int(msg.param2) if int(msg.param1) & 1 else None
            return self._set_mode_common(custom, now)
        if msg.command == mavlink2.MAV_CMD_NAV_TAKEOFF and self.flying is not None:
            ok = self.armed and self.flying.takeoff(msg)
            return mavlink2.MAV_RESULT_ACCEPTED if ok else mavlink2.MAV_RESULT_FAILED
        return mavlink2.MAV_RESULT_UNSUPPORTED

    def _gcs_sysid_name(self) -> str:
        return "MAV_GCS_SYSID" if self.opt.release is Release.MASTER_2025 else "SYSID_MYGCS"

    # --- modes -----------------------------------------------------------------------------

    def position_ok(self, now: float) -> bool:
        """Copter::position_ok: no EKF failsafe and a (relative or absolute) position."""
        flags = self.ekf.status(now)
        if self.armed:
            return not self.failsafe_ekf and flags["horiz_pos_abs"] and \
                not flags["const_pos_mode"]
        return not self.failsafe_ekf and flags["horiz_pos_abs"]

    def ekf_alt_ok(self, now: float) -> bool:
        flags = self.ekf.status(now)
        return flags["vert_vel"] and flags["vert_pos"]

    def _set_mode_common(self, custom: int | None, now: float) -> int:
        """_set_mode_common: only custom modes; a refused mode is MAV_RESULT_FAILED."""
        if custom is None or custom not in MODES:
            return mavlink2.MAV_RESULT_FAILED
        ok = self.set_mode(MODES[custom], now)
        return mavlink2.MAV_RESULT_ACCEPTED if ok else mavlink2.MAV_RESULT_FAILED

    def set_mode(self, mode: Mode, now: float, reason: str = "GCS") -> bool:
        """Copter::set_mode's entry checks: 'requires position', 'need alt estimate'."""
        failure = None
        if mode.requires_position and not self.position_ok(now):
            failure = "requires position"
        elif not self.ekf_alt_ok(now) and self.mode.manual_throttle and \
                not mode.manual_throttle:
            failure = "need alt estimate"
        if failure:
            self.say(Severity.WARNING, f"Mode change to {mode.name} failed: {failure}", now)
            self.record.events.append(Event(now, EventKind.MODE_REFUSED, mode.name))
            return False
        self._enter_mode(mode, now)
        return True

    def _enter_mode(self, mode: Mode, now: float, pause: bool = False) -> None:
        self.mode = mode
        self.record.events.append(Event(now, EventKind.MODE, mode.name))
        if self.flying is not None:
            self.flying.flight.set_mode(mode.number, pause)

    # --- arming ----------------------------------------------------------------------------

    def _arm_disarm(self, msg: object, now: float) -> int:
        if msg.param1 == 1:
            if self.armed:
                return mavlink2.MAV_RESULT_ACCEPTED
            forced = msg.param2 in (FORCE_ARM, FORCE_ARM_DISARM)
            return self.arm(now, checks=not forced)
        if msg.param1 == 0:
            if not self.armed:
                return mavlink2.MAV_RESULT_ACCEPTED
            if self._in_the_air() and msg.param2 != FORCE_ARM_DISARM:
                return mavlink2.MAV_RESULT_FAILED
            self._disarm(now, "GCS")
            return mavlink2.MAV_RESULT_ACCEPTED
        return mavlink2.MAV_RESULT_UNSUPPORTED

    def _in_the_air(self) -> bool:
        """Not landed: the land detector's verdict on a flying vehicle; on a scripted one,
        more than FLYING_HEIGHT_M above the boot height."""
        if self.flying is not None:
            return not self.flying.flight.land.complete
        return self._height_above_boot() > FLYING_HEIGHT_M

    def _disarm(self, now: float, why: str) -> None:
        self.armed = False
        if self.flying is not None:
            self.flying.flight.disarm()
        self.record.events.append(Event(now, EventKind.DISARMED, why))

    def _height_above_boot(self) -> float:
        if self._boot_height is None:
            return 0.0
        return self._last_baro - self._boot_height

    def arm(self, now: float, checks: bool = True) -> int:
        """AP_Arming_Copter::arm: pre-arm checks (all reported), then arm checks."""
        failures = [f"PreArm: {f}" for f in self.pre_arm_failures(now, checks)]
        if not failures and not self.mode.allows_arming:
            failures = [f"Arm: {self.mode.name} mode not armable"]
        if failures:
            for text in failures:
                self.say(Severity.CRITICAL, text, now)
            self.record.events.append(Event(now, EventKind.ARMING_REFUSED, failures[0]))
            return mavlink2.MAV_RESULT_FAILED
        home_set = self.origin is not None and self.position_ok(now)
        if not home_set:
            self.ekf.reset_height_datum(self._last_baro, now, not self._in_the_air())
        self.armed = True
        if self.flying is not None:
            self.flying.flight.arm()
        self.record.events.append(Event(now, EventKind.ARMED, self.mode.name))
        return mavlink2.MAV_RESULT_ACCEPTED

    def pre_arm_failures(self, now: float, checks: bool = True) -> list[str]:
        """The failing pre-arm checks that matter for a vision set-up, in the order run_pre_
        arm_checks reports them; ARMING_CHECK 0 (or a forced arm) leaves the mandatory ones."""
        arming_check = int(self.params.get("ARMING_CHECK")) if checks else 0
        failures = self._mandatory_failures(now)
        if arming_check & (ARMING_CHECK_ALL | ARMING_CHECK_VISION):
            vision = self.visual_odom.pre_arm_failure(now)
            if vision:
                failures.append(f"VisOdom: {vision}")
        return failures

    def _mandatory_failures(self, now: float) -> list[str]:
        """mandatory_position_checks (AHRS, EKF3 source availability, position) and
        alt_checks."""
        failures = []
        if not self.ekf.started:
            failures.append("AHRS: Not healthy")
        else:
            source = self._source_failure(self.mode.requires_position)
            if source:
                failures.append(f"AHRS: {source}")
            elif self.mode.requires_position and not self.position_ok(now):
                failures.append("Need Position Estimate")
        if not self.mode.manual_throttle and not self.ekf_alt_ok(now):
            failures.append("Need Alt Estimate")
        return failures

    def _source_failure(self, requires_position: bool) -> str | None:
        """AP_NavEKF_Source::pre_arm_check for the sensors modelled: GPS (none is ever
        connected here) and VisualOdom (VISO_TYPE)."""
        src = {k: int(self.params.get(f"EK3_SRC1_{k}")) for k in ("POSXY", "VELXY", "POSZ",
                                                                    "VELZ", "YAW")}
        used = list(src.values()) if requires_position else [src["YAW"]]
        if requires_position and 3 in (src["POSXY"], src["VELXY"], src["POSZ"], src["VELZ"]):
            return "EK3 sources require GPS"
        if 6 in used and not self.visual_odom.enabled:
            return "EK3 sources require VisualOdom"
        return None

    # --- EKF failsafe ----------------------------------------------------------------------

    def _run_ekf_check(self, now: float) -> None:
        """ekf_check.cpp: armed, variances over FS_EKF_THRESH or no position for 1 s: 'EKF
        variance', and in a position mode the failsafe action (FS_EKF_ACTION 1: LAND)."""
        count = self._ekf_check[1]
        thresh = self.params.get("FS_EKF_THRESH")
        if not self.armed or thresh <= 0:
            self._ekf_check = (now, 0)
            return
        ratios = self.ekf.ratios
        over = 0 + (2 if ratios["vel"] >= (2 * thresh) ** 2 else
                    1 if ratios["vel"] >= thresh ** 2 else 0)
        over_threshold = (ratios["pos"] >= thresh ** 2 and over >= 1) or over >= 2
        failing = over_threshold or not self.position_ok(now)
        count = min(count + 1, EKF_CHECK_ITERATIONS) if failing else 0
        self._ekf_check = (now, count)
        if count == EKF_CHECK_ITERATIONS and not self.failsafe_ekf:
            self.failsafe_ekf = True
            self.say(Severity.CRITICAL, "EKF variance", now)
            self.record.events.append(Event(now, EventKind.FAILSAFE, "EKF"))
            if self.mode.requires_position and self.params.get("FS_EKF_ACTION") > 0:
                self._enter_mode(MODES[9], now, pause=True)  # set_mode_land_with_pause
                self.say(Severity.CRITICAL, "EKF Failsafe: changed to LAND Mode", now)
        elif count == 0 and self.failsafe_ekf:
            self.failsafe_ekf = False


class _Reported:
    """A flight controller's present readings in the shape sensor_message reads."""

    def __init__(self, state: dict) -> None:
        self._state = state

    def state(self, _t: float) -> dict:
        return dict(self._state)
