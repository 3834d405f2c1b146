"""ArduCopter's flight-control parameters the flying simulator reads, with the firmware's
defaults and units (ArduCopter Parameters.cpp and config.h; AC_AttitudeControl(_Multi),
AC_PosControl, AC_WPNav, AC_Loiter, AP_MotorsMulticopter, AP_InertialSensor, AP_RangeFinder
var_info tables). Copter 4.7 renamed many of these to SI names (LAND_SPD_MS, WP_SPD,
PSC_NE_POS_P, ATC_ANGLE_MAX, ...); the simulator keeps the 4.5 names in both releases.
"""

from __future__ import annotations

from sim.autopilot.params import INT8, INT16, REAL32, ParamSpec, _specs

RATE_RP = {"P": 0.135, "I": 0.135, "D": 0.0036, "IMAX": 0.5, "FLTT": 20.0, "FLTE": 0.0,
           "FLTD": 20.0}  # AC_ATC_MULTI_RATE_RP_* and AC_ATC_MULTI_RATE_RPY_FILT_HZ
RATE_YAW = {"P": 0.18, "I": 0.018, "D": 0.0, "IMAX": 0.5, "FLTT": 20.0, "FLTE": 2.5,
            "FLTD": 20.0}  # AC_ATC_MULTI_RATE_YAW_*


def flight_specs() -> dict[str, ParamSpec]:
    """The flight-control parameter table of a fresh ArduCopter (4.5 names and units)."""
    rates = {f"ATC_RAT_{axis}_{k}": v for axis, gains in
             (("RLL", RATE_RP), ("PIT", RATE_RP), ("YAW", RATE_YAW)) for k, v in gains.items()}
    return {
        **_specs(REAL32, **rates, ATC_ANG_RLL_P=4.5, ATC_ANG_PIT_P=4.5, ATC_ANG_YAW_P=4.5,
                 ATC_ACCEL_R_MAX=110000.0, ATC_ACCEL_P_MAX=110000.0, ATC_ACCEL_Y_MAX=27000.0,
                 ATC_SLEW_YAW=6000.0, ATC_INPUT_TC=0.15, ATC_THR_MIX_MIN=0.1,
                 PSC_POSXY_P=1.0, PSC_VELXY_P=2.0, PSC_VELXY_I=1.0, PSC_VELXY_D=0.5,
                 PSC_VELXY_IMAX=1000.0, PSC_VELXY_FLTE=5.0, PSC_VELXY_FLTD=5.0,
                 PSC_POSZ_P=1.0, PSC_VELZ_P=5.0, PSC_VELZ_I=0.0, PSC_VELZ_IMAX=1000.0,
                 PSC_ACCZ_P=0.5, PSC_ACCZ_I=1.0, PSC_ACCZ_D=0.0, PSC_ACCZ_IMAX=800.0,
                 PSC_ACCZ_FLTE=20.0, PSC_JERK_XY=5.0, PSC_JERK_Z=5.0, PSC_ANGLE_MAX=0.0,
                 WPNAV_SPEED=1000.0, WPNAV_ACCEL=250.0, WPNAV_SPEED_UP=250.0,
                 WPNAV_SPEED_DN=150.0, WPNAV_ACCEL_Z=100.0,
                 LOIT_SPEED=1250.0, LOIT_ACC_MAX=500.0, LOIT_BRK_ACCEL=250.0,
                 LOIT_BRK_JERK=500.0, LOIT_BRK_DELAY=1.0, LOIT_ANG_MAX=0.0,
                 PILOT_Y_RATE=202.5, MOT_SPIN_ARM=0.10, MOT_SPIN_MIN=0.15, MOT_SPIN_MAX=0.95,
                 MOT_THST_EXPO=0.65, MOT_THST_HOVER=0.35, MOT_SPOOL_TIME=0.5,
                 INS_GYRO_FILTER=20.0, INS_ACCEL_FILTER=20.0, EK3_GND_EFF_DZ=4.0,
                 DISARM_DELAY=10.0, TKOFF_SLEW_TIME=2.0, TKOFF_THR_MAX=0.9),
        **_specs(INT16, ANGLE_MAX=3000, LAND_SPEED=50, LAND_SPEED_HIGH=0, PILOT_SPEED_UP=250,
                 PILOT_SPEED_DN=0, PILOT_ACCEL_Z=250, PILOT_TKOFF_ALT=0, THR_DZ=100,
                 MOT_YAW_HEADROOM=200, RNGFND1_MIN_CM=20, RNGFND1_MAX_CM=700,
                 RC_OVERRIDE_TIME=3),
        **_specs(INT8, WP_YAW_BEHAVIOR=2, MOT_HOVER_LEARN=2, GND_EFFECT_COMP=1,
                 RNGFND1_ORIENT=25),
        **_specs(INT8, True, RNGFND1_TYPE=0),
        "LAND_ALT_LOW": ParamSpec(1000, INT16),
    }
