"""What the service needs the autopilot to stream, and how each autopilot is made to stream it.

This module is the product's one place for that knowledge; the service (daemon/streams.py) and
`sdvl check-autopilot` both use it.

ArduPilot (libraries/GCS_MAVLink/GCS_Common.cpp, GCS_MAVLink_Parameters.cpp, upstream 2025):
- MAV_CMD_SET_MESSAGE_INTERVAL sets one message's interval on the channel the command came
  in on, until the next reboot; a message it cannot map is DENIED.
- REQUEST_DATA_STREAM sets the rate of a whole stream group on that channel.
- A non-GCS port streams nothing unless asked (observed on ArduCopter, autopilot-interface.md
  (e) 1). Each group's rate on each MAVLink port is a parameter: MAVn_<GROUP> since 4.7 (n = 1
  for the first MAVLink port), SRn_<GROUP> before (n from 0). n counts the SERIALx ports whose
  SERIALx_PROTOCOL is MAVLink (1 or 2) in order, so it is the port's place among the MAVLink
  ports, not its SERIAL number (ArduPilot issue #28646).
- Groups of the messages used here: RAW_SENS (RAW_IMU, SCALED_PRESSURE), EXT_STAT (SYS_STATUS,
  GPS_RAW_INT), POSITION (GLOBAL_POSITION_INT, LOCAL_POSITION_NED), EXTRA1 (ATTITUDE), EXTRA3
  (DISTANCE_SENSOR, SYSTEM_TIME, EKF_STATUS_REPORT).
PX4 (src/modules/mavlink/mavlink_main.cpp, mavlink_receiver.cpp): each MAVLink instance n streams
the set of its MAV_n_MODE, within MAV_n_RATE bytes/s; Onboard (2) streams ATTITUDE 100 Hz,
HIGHRES_IMU 50 Hz, LOCAL_POSITION_NED 30 Hz, ALTITUDE 10 Hz and DISTANCE_SENSOR 10 Hz, and
MAV_CMD_SET_MESSAGE_INTERVAL changes one stream's rate.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink2

MAV_CMD_SET_MESSAGE_INTERVAL = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
SERIAL_PORTS = range(10)  # SERIAL0..SERIAL9
MAVLINK_PROTOCOLS = (1, 2)  # SERIALx_PROTOCOL: MAVLink 1, MAVLink 2
PX4_INSTANCES = range(3)  # MAV_0_* .. MAV_2_*
PX4_MODES = {0: "Normal", 1: "Custom", 2: "Onboard", 3: "OSD", 4: "Magic", 5: "Config",
             7: "Minimal", 8: "External Vision", 9: "External Vision Minimal", 10: "Gimbal",
             11: "Onboard Low Bandwidth", 12: "uAvionix"}
# modes whose default streams hold everything NEEDS asks of PX4 (mavlink_main.cpp)
PX4_SUFFICIENT_MODES = (2, 5, 8)
PX4_ONBOARD = 2
PX4_PORTS = {0: "disabled", 101: "TELEM 1", 102: "TELEM 2", 103: "TELEM 3", 104: "TELEM 4",
             201: "GPS 1", 202: "GPS 2", 300: "Radio Controller", 301: "Wifi Port"}

ARDUPILOT_GROUPS = {"RAW_IMU": "RAW_SENS", "SCALED_PRESSURE": "RAW_SENS",
                    "SYS_STATUS": "EXT_STAT", "GPS_RAW_INT": "EXT_STAT",
                    "GLOBAL_POSITION_INT": "POSITION", "LOCAL_POSITION_NED": "POSITION",
                    "ATTITUDE": "EXTRA1", "DISTANCE_SENSOR": "EXTRA3", "SYSTEM_TIME": "EXTRA3",
                    "EKF_STATUS_REPORT": "EXTRA3"}
DATA_STREAM_IDS = {"RAW_SENS": mavlink2.MAV_DATA_STREAM_RAW_SENSORS,
                   "EXT_STAT": mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS,
                   "POSITION": mavlink2.MAV_DATA_STREAM_POSITION,
                   "EXTRA1": mavlink2.MAV_DATA_STREAM_EXTRA1,
                   "EXTRA3": mavlink2.MAV_DATA_STREAM_EXTRA3}


class Presence(Enum):
    """When an autopilot sends a message at all."""

    ALWAYS = "always"  # every autopilot has the sensor: missing means not streamed
    SENSOR = "sensor"  # only when the sensor is fitted (a downward rangefinder)
    ESTIMATE = "estimate"  # only once the autopilot's EKF has a position


@dataclass(frozen=True)
class Need:
    """One kind of data the service uses: the message asked for, the messages that carry it
    (daemon/fusion/sensors.py reads any of them), the rate asked and the least that is usable."""

    kind: str
    request: str
    accepts: tuple[str, ...]
    rate_hz: float
    min_hz: float
    presence: Presence = Presence.ALWAYS

    @property
    def message_id(self) -> int:
        """The MAVLink id of the message asked for."""
        return getattr(mavlink2, f"MAVLINK_MSG_ID_{self.request}")


IMU_MESSAGES = ("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU")
BARO_MESSAGES = ("SCALED_PRESSURE", "HIGHRES_IMU", "ALTITUDE")
# the fusion drops the IMU after imu_timeout_s (0.1 s) without a sample: at least 20 Hz
_ATTITUDE = Need("attitude", "ATTITUDE", ("ATTITUDE",), 50.0, 10.0)
_RANGE = Need("downward rangefinder", "DISTANCE_SENSOR", ("DISTANCE_SENSOR",), 20.0, 5.0,
              Presence.SENSOR)
_LOCAL = Need("local position (height origin)", "LOCAL_POSITION_NED", ("LOCAL_POSITION_NED",),
              10.0, 1.0, Presence.ESTIMATE)
NEEDS: dict[str, tuple[Need, ...]] = {
    "ardupilot": (_ATTITUDE, Need("IMU", "RAW_IMU", IMU_MESSAGES, 50.0, 20.0),
                  Need("barometer", "SCALED_PRESSURE", BARO_MESSAGES, 10.0, 2.0),
                  _RANGE, _LOCAL),
    "px4": (_ATTITUDE, Need("IMU", "HIGHRES_IMU", IMU_MESSAGES, 50.0, 20.0),
            Need("barometer", "ALTITUDE", BARO_MESSAGES, 10.0, 2.0), _RANGE, _LOCAL,
            # PX4's land detector: on the ground the fusion holds the vehicle still (ArduPilot
            # says it in HEARTBEAT's system status)
            Need("land detector", "EXTENDED_SYS_STATE", ("EXTENDED_SYS_STATE",), 5.0, 1.0)),
}


def needs_for(flavour: str) -> tuple[Need, ...]:
    """What to ask of an autopilot ('ardupilot', 'px4'; anything else is asked like PX4)."""
    return NEEDS.get(flavour, NEEDS["px4"])


@dataclass(frozen=True)
class ParamHint:
    """A parameter that would make the autopilot send a message: set `name` to `value`
    (`where`: on which port, when the port is not known)."""

    name: str
    value: float
    where: str

    def __str__(self) -> str:
        return f"{self.name} = {self.value:g}" + (f" ({self.where})" if self.where else "")


def ardupilot_naming(params: Mapping[str, float]) -> str | None:
    """'MAV' (4.7+), 'SR' (older) or None when the parameters read do not tell."""
    for family, pattern in (("MAV", r"MAV\d+_EXTRA1"), ("SR", r"SR\d+_EXTRA1")):
        if any(re.fullmatch(pattern, name) for name in params):
            return family
    return None


def mavlink_ports(params: Mapping[str, float]) -> list[int]:
    """The SERIAL ports that speak MAVLink, in order (SERIAL0, the USB port, counts even where
    SERIAL0_PROTOCOL does not exist)."""
    ports = [x for x in SERIAL_PORTS if params.get(f"SERIAL{x}_PROTOCOL") in MAVLINK_PROTOCOLS]
    if "SERIAL0_PROTOCOL" not in params and 0 not in ports:
        ports.insert(0, 0)
    return ports


def ardupilot_rate_params(group: str, params: Mapping[str, float],
                          usb: bool) -> list[tuple[str, int]]:
    """(parameter name, SERIAL port) of the group's rate on each port the companion may be on:
    SERIAL0 over USB, else every other MAVLink port."""
    family = ardupilot_naming(params) or "MAV"
    ports = mavlink_ports(params)
    chosen = [0] if usb else [x for x in ports if x != 0] or ports
    out = []
    for x in chosen:
        channel = ports.index(x) if x in ports else x
        index = channel + 1 if family == "MAV" else channel
        out.append((f"{family}{index}_{group}", x))
    return out


def px4_instances(params: Mapping[str, float]) -> list[int]:
    """The PX4 MAVLink instances that are configured (MAV_n_CONFIG not 0, or unknown)."""
    return [n for n in PX4_INSTANCES
            if f"MAV_{n}_MODE" in params and params.get(f"MAV_{n}_CONFIG", 1) != 0]


def stream_hints(flavour: str, need: Need, params: Mapping[str, float],
                 usb: bool) -> list[ParamHint]:
    """Parameters that would make this autopilot send `need` on the companion's port."""
    if flavour == "ardupilot":
        group = ARDUPILOT_GROUPS[need.request]
        return [ParamHint(name, need.rate_hz, f"if the companion is on SERIAL{x}")
                for name, x in ardupilot_rate_params(group, params, usb)]
    hints = []
    for n in px4_instances(params):
        port = PX4_PORTS.get(int(params.get(f"MAV_{n}_CONFIG", -1)), "")
        where = f"if the companion is on instance {n}" + (f", {port}" if port else "")
        if params[f"MAV_{n}_MODE"] in PX4_SUFFICIENT_MODES:
            hints.append(ParamHint(f"MAV_{n}_RATE", 0, where + ": 0 = as fast as the port"))
        else:
            hints.append(ParamHint(f"MAV_{n}_MODE", PX4_ONBOARD, where + ", Onboard"))
    return hints


def generic_hint(flavour: str, need: Need) -> str:
    """The parameter family when this autopilot's parameters are not known."""
    if flavour == "ardupilot":
        group = ARDUPILOT_GROUPS[need.request]
        return (f"MAVn_{group} (ArduPilot 4.7+; SRn_{group} before), n the companion port's "
                "place among the MAVLink ports")
    return "MAV_n_MODE = 2 (Onboard) on the companion's MAVLink instance"
