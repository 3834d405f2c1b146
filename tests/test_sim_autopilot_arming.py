"""Arming and flight modes of the simulated autopilots: the pre-arm checks a vision set-up meets
(ArduCopter's VisOdom health and attitude checks, position and altitude estimates, PX4's mode
requirements), mode entry requirements, the armed state in HEARTBEAT (virtual clock)."""

from __future__ import annotations

import re

import numpy as np
from autopilot_helpers import Companion, takeoff
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import SimOptions, configured_options
from sim.autopilot.virtual import VirtualLink

ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
SET_MODE = mavlink2.MAV_CMD_DO_SET_MODE
ACCEPTED, FAILED = mavlink2.MAV_RESULT_ACCEPTED, mavlink2.MAV_RESULT_FAILED
LOITER, LAND = 5, 9


def vision_link(viso_type: int = 2, ground_s: float = 2.0, **changes) -> VirtualLink:
    return VirtualLink(configured_options(viso_type=viso_type, requested={},
                                          trajectory=takeoff(ground_s=ground_s), **changes))


def test_no_vision_refuses_arming_with_the_real_text():
    link = vision_link()
    link.advance(1.0)
    assert link.command(ARM, 1) == FAILED
    assert "PreArm: VisOdom: not healthy" in link.texts()


def test_vision_lets_it_arm_and_heartbeat_says_armed_until_vision_is_300_ms_old():
    link = vision_link(ground_s=10.0)
    companion = Companion(link)
    companion.fly(2.0)
    assert link.command(ARM, 1) == ACCEPTED
    companion.fly(1.1)
    assert link.of("HEARTBEAT")[-1].base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    assert link.command(ARM, 0) == ACCEPTED  # on the ground
    link.advance(0.2)
    assert link.model.visual_odom.healthy(link.now)
    link.advance(0.15)
    assert link.command(ARM, 1) == FAILED
    assert link.texts()[-1] == "PreArm: VisOdom: not healthy"


def test_type_2_attitude_checks_after_its_yaw_alignment():
    link = vision_link()
    companion = Companion(link, yaw_offset_deg=40.0)
    companion.fly(1.0)
    shifted = [t for t in link.texts() if t.startswith("VisOdom: yaw shifted")]
    assert re.fullmatch(r"VisOdom: yaw shifted 3(19|20) to (29|30) deg", shifted[0])  # to 30
    assert link.model.pre_arm_failures(link.now) == []
    companion.yaw_offset_deg = 60.0  # the camera's heading drifts 20 deg afterwards
    companion.fly(0.5)
    assert link.command(ARM, 1) == FAILED
    assert link.texts()[-1] == "PreArm: VisOdom: yaw diff 20.0 deg (>10)"


def test_arming_check_zero_leaves_only_the_mandatory_checks():
    link = vision_link(param_overrides={"ARMING_CHECK": 0})
    link.advance(1.0)
    assert link.command(ARM, 1) == ACCEPTED


def test_loiter_needs_a_position_and_gets_one_from_external_nav():
    link = vision_link()
    link.advance(1.0)
    assert link.command(SET_MODE, 1, LOITER) == FAILED
    assert link.texts()[-1] == "Mode change to LOITER failed: requires position"
    Companion(link).fly(2.0)
    assert link.command(SET_MODE, 1, LOITER) == ACCEPTED
    assert link.command(ARM, 1) == ACCEPTED
    link.advance(0.1)
    heartbeat = link.of("HEARTBEAT")[-1]
    assert heartbeat.custom_mode == LOITER and heartbeat.system_status == \
        mavlink2.MAV_STATE_ACTIVE


def test_position_mode_checks_name_the_missing_sensor():
    """In a mode that needs a position, EKF3 sources that need a GPS (none is connected) or
    VisualOdom (VISO_TYPE 0) are pre-arm failures of their own (the model in LOITER directly:
    a real one cannot get there without a position either)."""
    fresh = VirtualLink(SimOptions())
    fresh.advance(0.5)
    fresh.model.mode = fresh.model.MODES[LOITER]
    assert fresh.model.pre_arm_failures(fresh.now)[0] == "AHRS: EK3 sources require GPS"
    no_viso = VirtualLink(configured_options(viso_type=0))
    no_viso.advance(0.5)
    no_viso.model.mode = no_viso.model.MODES[LOITER]
    assert no_viso.model.pre_arm_failures(no_viso.now)[0] == \
        "AHRS: EK3 sources require VisualOdom"


def test_land_is_not_armable_and_a_flying_vehicle_is_not_disarmed():
    link = vision_link()
    companion = Companion(link)
    companion.fly(1.0)
    link.command(SET_MODE, 1, LAND)
    assert link.command(ARM, 1) == FAILED
    assert link.texts()[-1] == "Arm: LAND mode not armable"
    link.command(SET_MODE, 1, 0)
    assert link.command(ARM, 1) == ACCEPTED
    companion.fly(4.0)  # the vehicle climbs to 3.4 m
    assert link.command(ARM, 0) == FAILED
    assert link.command(ARM, 0, 21196) == ACCEPTED


def test_ekf_failsafe_lands_when_vision_stops_in_loiter():
    link = vision_link()
    companion = Companion(link)
    companion.fly(2.0)
    link.command(SET_MODE, 1, LOITER)
    link.command(ARM, 1)
    companion.fly(3.0)
    link.advance(10.0)  # no vision: position times out after 7 s, failsafe 1 s later
    texts = link.texts()
    assert "EKF variance" in texts and "EKF Failsafe: changed to LAND Mode" in texts
    assert link.of("HEARTBEAT")[-1].custom_mode == LAND


def test_px4_position_mode_needs_external_vision():
    link = VirtualLink(configured_options("px4", requested={}, trajectory=takeoff()))
    link.advance(1.0)
    position = (mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3, 0)
    assert link.command(SET_MODE, *position) == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
    assert link.command(ARM, 1) == ACCEPTED  # Manual needs nothing
    link.command(ARM, 0)
    Companion(link).fly(1.0)
    assert link.command(SET_MODE, *position) == ACCEPTED
    link.advance(1.0)  # vision stops: the position estimate goes
    assert link.command(ARM, 1) == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
    assert link.texts()[-1] == "Arming denied: Resolve system health failures first"
    assert np.isfinite(link.model.ekf.filter.position).all()
