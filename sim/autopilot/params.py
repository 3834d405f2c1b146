"""Parameter tables of the simulated autopilots as a fresh firmware has them, and the set a
correct `sdvl check-autopilot --apply` leaves.

Every default is the firmware's own (sources in sim/autopilot/BEHAVIOUR.md, section
"Parameters"); names depend on the release: ArduPilot master of mid-2025 renamed `GPS_TYPE` ->
`GPS1_TYPE`, `SRn_*` -> `MAVn_*` and `SYSID_THISMAV`/`SYSID_MYGCS` -> `MAV_SYSID`/
`MAV_GCS_SYSID`; 4.5 still has the old names.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink2

REAL32 = mavlink2.MAV_PARAM_TYPE_REAL32
INT32 = mavlink2.MAV_PARAM_TYPE_INT32
INT16 = mavlink2.MAV_PARAM_TYPE_INT16
INT8 = mavlink2.MAV_PARAM_TYPE_INT8

# ArduPilot's stream groups in parameter order (GCS_MAVLink_Parameters.cpp var_info)
STREAM_GROUPS = ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2",
                 "EXTRA3", "PARAMS", "ADSB")
SERIAL_PORTS = 7  # SERIAL0..SERIAL6 on a typical flight controller
MAVLINK_PROTOCOLS = (1, 2)  # SERIALn_PROTOCOL values that start a MAVLink channel
# AP_SerialManager.cpp DEFAULT_SERIALn_PROTOCOL / _BAUD: 0-2 MAVLink2, 3-4 GPS, others none
SERIAL_DEFAULTS = {0: (2, 115), 1: (2, 57), 2: (2, 57), 3: (5, 38), 4: (5, 38), 5: (-1, 57),
                   6: (-1, 57)}
PX4_PORTS = {"TEL1": 101, "TEL2": 102, "TEL3": 103, "TEL4": 104}  # MAV_n_CONFIG values


class Release(Enum):
    """Which ArduPilot firmware's parameter names the simulator has."""

    MASTER_2025 = "master-2025"  # GPS1_TYPE, MAVn_*, MAV_SYSID, MAV_GCS_SYSID
    COPTER_4_5 = "4.5"  # GPS_TYPE, SRn_*, SYSID_THISMAV, SYSID_MYGCS


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: firmware default, MAVLink type, and whether the running firmware only
    takes a new value at the next boot (@RebootRequired in the source)."""

    default: float
    kind: int
    reboot: bool = False


def _specs(kind: int, reboot: bool = False, **defaults: float) -> dict[str, ParamSpec]:
    return {name: ParamSpec(value, kind, reboot) for name, value in defaults.items()}


def _ardupilot_core() -> dict[str, ParamSpec]:
    """Names both releases share: AP_VisualOdom.cpp, AP_NavEKF3.cpp, AP_NavEKF_Source.cpp,
    AP_AHRS.cpp, AP_Arming.cpp, Compass, ArduCopter Parameters.cpp defaults."""
    return {
        **_specs(INT8, True, VISO_TYPE=0, EK3_ENABLE=1, EK2_ENABLE=0),
        **_specs(REAL32, VISO_POS_X=0.0, VISO_POS_Y=0.0, VISO_POS_Z=0.0, VISO_SCALE=1.0,
                 VISO_VEL_M_NSE=0.1, VISO_POS_M_NSE=0.2, VISO_YAW_M_NSE=0.2,
                 EK3_ALT_M_NSE=2.0, EK3_ACC_P_NSE=0.35, FS_EKF_THRESH=0.8),
        **_specs(INT8, VISO_ORIENT=0, VISO_QUAL_MIN=0, AHRS_EKF_TYPE=3, EK3_SRC1_POSXY=3,
                 EK3_SRC1_VELXY=3, EK3_SRC1_POSZ=1, EK3_SRC1_VELZ=3, EK3_SRC1_YAW=1,
                 COMPASS_USE=1, COMPASS_ENABLE=1, FS_EKF_ACTION=1),
        **_specs(INT16, VISO_DELAY_MS=10, EK3_SRC_OPTIONS=1, EK3_POS_I_GATE=500,
                 EK3_VEL_I_GATE=500, EK3_HGT_I_GATE=500),
        **_specs(INT32, ARMING_CHECK=1),
    }


def _serial_specs() -> dict[str, ParamSpec]:
    out: dict[str, ParamSpec] = {}
    for n, (protocol, baud) in SERIAL_DEFAULTS.items():
        out[f"SERIAL{n}_PROTOCOL"] = ParamSpec(protocol, INT8, True)
        out[f"SERIAL{n}_BAUD"] = ParamSpec(baud, INT32, True)
        out[f"SERIAL{n}_OPTIONS"] = ParamSpec(0, INT16, True)
    return out


def mavlink_channel(params: dict[str, float], serial: int) -> int | None:
    """ArduPilot's MAVLink channel index of SERIALn: channels go to the MAVLink ports in port
    order (AP_SerialManager::get_mavlink_channel); None when SERIALn is not MAVLink."""
    if params.get(f"SERIAL{serial}_PROTOCOL") not in MAVLINK_PROTOCOLS:
        return None
    return sum(params.get(f"SERIAL{k}_PROTOCOL") in MAVLINK_PROTOCOLS for k in range(serial))


def stream_rate_name(release: Release, channel: int, group: str) -> str:
    """The stream-rate parameter of a channel's group: MAV{channel+1}_{group} on master-2025,
    SR{channel}_{group} on 4.5."""
    if release is Release.MASTER_2025:
        return f"MAV{channel + 1}_{group}"
    return f"SR{channel}_{group}"


def _stream_specs(release: Release, channels: int) -> dict[str, ParamSpec]:
    """Copter's stream rates all default to 0 (GCS_MAVLink_Parameters.cpp,
    AP_MAV_DEFAULT_STREAM_RATE_* for APM_BUILD_COPTER_OR_HELI); reboot required. master-2025
    has MAVn_* for the channels that exist; 4.5 has SR0..SR6 whether or not the port is
    MAVLink."""
    if release is Release.COPTER_4_5:
        channels = SERIAL_PORTS
    out = {stream_rate_name(release, c, g): ParamSpec(0, INT16, True)
           for c in range(channels) for g in STREAM_GROUPS}
    if release is Release.MASTER_2025:
        out.update({f"MAV{c + 1}_OPTIONS": ParamSpec(0, INT16, True) for c in range(channels)})
    return out


def ardupilot_specs(release: Release, stored: dict[str, float] | None = None
                    ) -> dict[str, ParamSpec]:
    """The parameter table of an ArduCopter of `release` whose stored values are `stored`
    (None: fresh): the MAVn_* that exist follow the SERIALn_PROTOCOLs."""
    protocols = {f"SERIAL{n}_PROTOCOL": p for n, (p, _) in SERIAL_DEFAULTS.items()}
    protocols.update({k: v for k, v in (stored or {}).items() if k in protocols})
    channels = sum(p in MAVLINK_PROTOCOLS for p in protocols.values())
    if release is Release.MASTER_2025:
        names = {**_specs(INT8, True, GPS1_TYPE=1, GPS2_TYPE=0),
                 **_specs(INT16, MAV_SYSID=1, MAV_GCS_SYSID=255)}
    else:
        names = {**_specs(INT8, True, GPS_TYPE=1, GPS_TYPE2=0),
                 **_specs(INT16, SYSID_THISMAV=1, SYSID_MYGCS=255)}
    return {**_ardupilot_core(), **_serial_specs(), **_stream_specs(release, channels),
            **names}


def px4_specs() -> dict[str, ParamSpec]:
    """A fresh PX4 v1.14: ekf2 params_external_vision.yaml, EKF2 height/GNSS params,
    mavlink module.yaml (MAV_n_*), commander (COM_ARM_WO_GPS)."""
    return {
        **_specs(INT32, EKF2_EV_CTRL=0, EKF2_HGT_REF=1, EKF2_EV_NOISE_MD=0, EKF2_EV_QMIN=0,
                 EKF2_GPS_CTRL=7, EKF2_BARO_CTRL=1, EKF2_RNG_CTRL=1, COM_ARM_WO_GPS=1),
        **_specs(REAL32, EKF2_EVP_NOISE=0.1, EKF2_EVV_NOISE=0.1, EKF2_EVA_NOISE=0.1,
                 EKF2_EVP_GATE=5.0, EKF2_EVV_GATE=3.0, EKF2_EV_POS_X=0.0, EKF2_EV_POS_Y=0.0,
                 EKF2_EV_POS_Z=0.0, EKF2_BARO_NOISE=3.5, EKF2_ACC_NOISE=0.35),
        **_specs(REAL32, True, EKF2_EV_DELAY=0.0),
        **_specs(INT32, True, MAV_0_CONFIG=101, MAV_1_CONFIG=0, MAV_2_CONFIG=0, MAV_0_MODE=0,
                 MAV_1_MODE=2, MAV_2_MODE=0, MAV_0_RATE=1200, MAV_1_RATE=0, MAV_2_RATE=0,
                 SER_TEL1_BAUD=57600, SER_TEL2_BAUD=57600, MAV_SYS_ID=1),
    }


def configured_values(flavour: str, release: Release = Release.MASTER_2025,
                      companion_serial: int = 2, viso_type: int = 2) -> dict[str, float]:
    """The parameters a correct `check-autopilot --apply` leaves, by this simulator's reading of
    issue 26: ArduPilot VISO_TYPE `viso_type` (2: what a real ArduCopter flew well with,
    autopilot-interface.md (e) 5), EK3 sources ExternalNav with baro height and compass yaw, no
    GPS, the VISO noise floors at their minimum (0.1 m, 0.05 rad) so the companion's covariance
    is used, VISO_DELAY_MS 40 (the 31-38 ms measured in (e) 7), MAVLink2 at 921600 on the
    companion's port and its stream rates (RAW_SENS 50 Hz, EXTRA1 50 Hz, EXTRA3 10 Hz,
    POSITION 10 Hz). PX4: EV horizontal+vertical position and velocity, no EV yaw (check-autopilot
    refuses it: daemon/px4_params.py), with baro height, MAVLink in Onboard mode on TELEM2 at
    921600."""
    if flavour == "px4":
        return {"EKF2_EV_CTRL": 7, "EKF2_HGT_REF": 0, "EKF2_GPS_CTRL": 0,
                "MAV_1_CONFIG": PX4_PORTS["TEL2"], "MAV_1_MODE": 2, "SER_TEL2_BAUD": 921600}
    values = {"VISO_TYPE": viso_type, "EK3_SRC1_POSXY": 6, "EK3_SRC1_VELXY": 6,
              "EK3_SRC1_POSZ": 1, "EK3_SRC1_VELZ": 6, "EK3_SRC1_YAW": 1, "VISO_POS_M_NSE": 0.1,
              "VISO_YAW_M_NSE": 0.05, "VISO_DELAY_MS": 40,
              "GPS1_TYPE" if release is Release.MASTER_2025 else "GPS_TYPE": 0,
              f"SERIAL{companion_serial}_PROTOCOL": 2,
              f"SERIAL{companion_serial}_BAUD": 921}
    channel = mavlink_channel({**{f"SERIAL{n}_PROTOCOL": p for n, (p, _) in
                                  SERIAL_DEFAULTS.items()}, **values}, companion_serial)
    for group, hz in (("RAW_SENS", 50), ("EXTRA1", 50), ("EXTRA3", 10), ("POSITION", 10)):
        values[stream_rate_name(release, channel, group)] = hz
    return values
