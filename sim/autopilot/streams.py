"""Which messages an autopilot streams on the companion's port, and at what interval.

ArduPilot: messages belong to stream groups whose rate parameters (MAVn_* / SRn_*) are read at
boot; REQUEST_DATA_STREAM sets a group's rate in RAM (Copter does not persist it,
GCS_MAVLINK::handle_request_data_stream with persist_streamrates() false) unless MAVn_OPTIONS
bit 2 says to ignore it; MAV_CMD_SET_MESSAGE_INTERVAL sets one message (GCS_MAVLINK::
set_message_interval: 0 = default, -1 = stop, under 1 ms = 1 ms). PX4: the instance's MAV_n_MODE
gives the streams and rates (Mavlink::configure_streams_to_default); SET_MESSAGE_INTERVAL sets
one (0 = the mode's default, HEARTBEAT refused); REQUEST_DATA_STREAM is ignored.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega

# GCS_MAVLink_Parameters.cpp STREAM_*_msgs for Copter (message names as MAVLink has them)
AP_GROUP_MESSAGES = {
    "RAW_SENS": ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3", "SCALED_PRESSURE",
                 "SCALED_PRESSURE2", "SCALED_PRESSURE3"),
    "EXT_STAT": ("SYS_STATUS", "POWER_STATUS", "MEMINFO", "MISSION_CURRENT", "GPS_RAW_INT",
                 "GPS_RTK", "GPS2_RAW", "GPS2_RTK", "NAV_CONTROLLER_OUTPUT", "FENCE_STATUS",
                 "POSITION_TARGET_GLOBAL_INT"),
    "RC_CHAN": ("SERVO_OUTPUT_RAW", "RC_CHANNELS"),
    "RAW_CTRL": (),
    "POSITION": ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    "EXTRA1": ("ATTITUDE", "AHRS2", "PID_TUNING"),
    "EXTRA2": ("VFR_HUD",),
    "EXTRA3": ("AHRS", "DISTANCE_SENSOR", "SYSTEM_TIME", "BATTERY_STATUS",
               "EKF_STATUS_REPORT", "VIBRATION"),
    "PARAMS": (),
    "ADSB": (),
}
# MAV_DATA_STREAM id -> group (handle_request_data_stream's switch); 0 = all but PARAMS
AP_DATA_STREAMS = {1: "RAW_SENS", 2: "EXT_STAT", 3: "RC_CHAN", 4: "RAW_CTRL", 6: "POSITION",
                   10: "EXTRA1", 11: "EXTRA2", 12: "EXTRA3"}
# mavlink_id_to_ap_message_id: messages SET_MESSAGE_INTERVAL/REQUEST_MESSAGE know (a subset of
# the real map: HIGHRES_IMU is there on boards with more than 1 MB of flash)
AP_KNOWN = {name for group in AP_GROUP_MESSAGES.values() for name in group} | {
    "HEARTBEAT", "SCALED_IMU", "HIGHRES_IMU", "HOME_POSITION", "GPS_GLOBAL_ORIGIN",
    "ATTITUDE_QUATERNION", "EXTENDED_SYS_STATE", "AUTOPILOT_VERSION", "RC_CHANNELS_RAW"}
AP_DEFAULT_INTERVAL = {"HEARTBEAT": 1.0}
# what a companion sends the autopilot its pose in
VISION_MESSAGES = ("ODOMETRY", "VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE")

# mavlink_main.cpp configure_streams_to_default, rates in Hz (v1.14+), per MAV_n_MODE, for the
# messages this simulator produces (Normal: only those read there; other modes: HEARTBEAT only)
PX4_MODE_STREAMS = {
    0: {"HEARTBEAT": 1.0, "SCALED_PRESSURE": 1.0, "SYS_STATUS": 1.0},
    1: {"HEARTBEAT": 1.0},
    2: {"HEARTBEAT": 1.0, "TIMESYNC": 10.0, "HIGHRES_IMU": 50.0, "LOCAL_POSITION_NED": 30.0,
        "ATTITUDE": 100.0, "ALTITUDE": 10.0, "DISTANCE_SENSOR": 10.0, "ODOMETRY": 30.0,
        "ATTITUDE_QUATERNION": 50.0, "SCALED_PRESSURE": 1.0, "SYS_STATUS": 5.0,
        "SYSTEM_TIME": 1.0, "ESTIMATOR_STATUS": 1.0, "EXTENDED_SYS_STATE": 5.0},
    8: {"HEARTBEAT": 1.0, "TIMESYNC": 10.0, "HIGHRES_IMU": 250.0, "LOCAL_POSITION_NED": 30.0,
        "ATTITUDE": 20.0, "ALTITUDE": 10.0, "DISTANCE_SENSOR": 10.0, "ODOMETRY": 30.0,
        "SCALED_PRESSURE": 1.0, "SYS_STATUS": 5.0},
}
PX4_KNOWN = {name for mode in PX4_MODE_STREAMS.values() for name in mode} | {
    "SCALED_IMU", "GPS_GLOBAL_ORIGIN", "HOME_POSITION"}


def message_name(msg_id: int) -> str | None:
    """MAVLink message name of an id, None when pymavlink does not know it."""
    cls = ardupilotmega.mavlink_map.get(int(msg_id))  # common plus ArduPilot's own
    return None if cls is None else cls.msgname


class Schedule:
    """Per-message send interval (seconds; absent or 0 = not sent) and the next due time."""

    def __init__(self) -> None:
        self.intervals: dict[str, float] = {}
        self._due: dict[str, float] = {}

    def set(self, name: str, interval_s: float) -> None:
        if interval_s > 0:
            self.intervals[name] = interval_s
        else:
            self.intervals.pop(name, None)
        self._due.pop(name, None)

    def rate_hz(self, name: str) -> float:
        interval = self.intervals.get(name, 0.0)
        return 1.0 / interval if interval > 0 else 0.0

    def due(self, now: float) -> list[str]:
        """Messages to send now; each is then due one interval later (no burst catch-up)."""
        out = []
        for name, interval in self.intervals.items():
            due = self._due.setdefault(name, now)
            if now >= due:
                out.append(name)
                self._due[name] = max(due + interval, now - interval)
        return out


def ardupilot_group_rates(schedule: Schedule, rates: dict[str, float]) -> None:
    """Set every message of each group to its group's rate (initialise_message_intervals_
    for_stream): a message in several groups takes the last set."""
    for group, hz in rates.items():
        for name in AP_GROUP_MESSAGES[group]:
            schedule.set(name, 1.0 / hz if hz > 0 else 0.0)


def interval_from_request(interval_us: float, default_s: float) -> float:
    """MAV_CMD_SET_MESSAGE_INTERVAL's param2 as the interval to use: 0 = the default,
    negative = stop, under 1 ms = 1 ms (both firmwares)."""
    if interval_us == 0:
        return default_s
    if interval_us < 0:
        return 0.0
    return max(interval_us, 1000.0) / 1e6
