"""Parameter tables of the simulated autopilots: a vision-ready set for each flavour."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

REAL32 = mavlink2.MAV_PARAM_TYPE_REAL32
INT32 = mavlink2.MAV_PARAM_TYPE_INT32
INT8 = mavlink2.MAV_PARAM_TYPE_INT8
INT16 = mavlink2.MAV_PARAM_TYPE_INT16

# name -> (value, MAV_PARAM_TYPE)
ARDUPILOT_PARAMS: dict[str, tuple[float, int]] = {
    "AHRS_EKF_TYPE": (3, INT8),
    "VISO_TYPE": (3, INT8),
    "VISO_POS_X": (0.0, REAL32), "VISO_POS_Y": (0.0, REAL32), "VISO_POS_Z": (0.0, REAL32),
    "VISO_ORIENT": (0, INT8),
    "VISO_SCALE": (1.0, REAL32),
    "VISO_DELAY_MS": (10, INT16),
    "VISO_VEL_M_NSE": (0.1, REAL32), "VISO_POS_M_NSE": (0.2, REAL32),
    "VISO_YAW_M_NSE": (0.2, REAL32),
    "VISO_QUAL_MIN": (0, INT8),
    "EK3_ENABLE": (1, INT8),
    "EK3_SRC1_POSXY": (6, INT8), "EK3_SRC1_VELXY": (6, INT8), "EK3_SRC1_POSZ": (1, INT8),
    "EK3_SRC1_VELZ": (6, INT8), "EK3_SRC1_YAW": (1, INT8),
    "GPS_TYPE": (0, INT8),
    "SERIAL2_PROTOCOL": (2, INT8),
}

PX4_PARAMS: dict[str, tuple[float, int]] = {
    "EKF2_EV_CTRL": (11, INT32),
    "EKF2_HGT_REF": (3, INT32),
    "EKF2_EV_DELAY": (0.0, REAL32),
    "EKF2_EV_NOISE_MD": (0, INT32),
    "EKF2_EV_QMIN": (0, INT32),
    "EKF2_EVP_NOISE": (0.1, REAL32), "EKF2_EVV_NOISE": (0.1, REAL32),
    "EKF2_EVA_NOISE": (0.1, REAL32),
    "EKF2_EV_POS_X": (0.0, REAL32), "EKF2_EV_POS_Y": (0.0, REAL32),
    "EKF2_EV_POS_Z": (0.0, REAL32),
    "EKF2_GPS_CTRL": (0, INT32),
}

