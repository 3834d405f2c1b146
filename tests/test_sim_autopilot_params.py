"""The simulated autopilots' parameters: names and defaults of a fresh firmware, PARAM_SET as
each firmware stores it, reboot-required parameters, what a reboot keeps (virtual clock)."""

from __future__ import annotations

import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import Release, SimOptions, configured_options
from sim.autopilot.params import INT32, REAL32
from sim.autopilot.virtual import VirtualLink


def read(link: VirtualLink, name: str) -> object | None:
    since = link.now
    link.send(link.mav.param_request_read_encode(1, 1, name.encode(), -1))
    values = [v for v in link.of("PARAM_VALUE", since) if v.param_id == name]
    return values[-1] if values else None


@pytest.mark.parametrize(("release", "present", "absent"), [
    (Release.MASTER_2025, ["GPS1_TYPE", "MAV3_EXTRA1", "MAV3_RAW_SENS", "MAV_GCS_SYSID",
                           "MAV_SYSID", "MAV3_OPTIONS"],
     ["GPS_TYPE", "SR2_EXTRA1", "SYSID_MYGCS", "MAV4_EXTRA1"]),
    (Release.COPTER_4_5, ["GPS_TYPE", "SR2_EXTRA1", "SR6_EXTRA3", "SYSID_MYGCS",
                          "SYSID_THISMAV"], ["GPS1_TYPE", "MAV3_EXTRA1", "MAV_GCS_SYSID"]),
])
def test_names_follow_the_release(release, present, absent):
    link = VirtualLink(SimOptions(release=release))
    for name in present:
        assert read(link, name) is not None, name
    for name in absent:
        assert read(link, name) is None, name


def test_fresh_ardupilot_is_not_vision_ready():
    link = VirtualLink(SimOptions())
    expected = {"VISO_TYPE": 0, "VISO_POS_M_NSE": 0.2, "VISO_YAW_M_NSE": 0.2,
                "VISO_DELAY_MS": 10, "EK3_SRC1_POSXY": 3, "EK3_SRC1_POSZ": 1, "GPS1_TYPE": 1,
                "ARMING_CHECK": 1, "AHRS_EKF_TYPE": 3, "MAV3_EXTRA1": 0, "SERIAL2_PROTOCOL": 2}
    for name, value in expected.items():
        assert read(link, name).param_value == pytest.approx(value), name
    assert read(link, "VISO_TYPE").param_type == mavlink2.MAV_PARAM_TYPE_INT8


def test_ardupilot_param_set_casts_to_the_parameter_type():
    link = VirtualLink(SimOptions())
    link.send(link.mav.param_set_encode(1, 1, b"VISO_DELAY_MS", 37.9, REAL32))
    link.send(link.mav.param_set_encode(1, 1, b"VISO_POS_M_NSE", 0.05, REAL32))
    link.send(link.mav.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, REAL32))
    answers = {v.param_id: v.param_value for v in link.of("PARAM_VALUE")}
    assert answers == {"VISO_DELAY_MS": 37.0, "VISO_POS_M_NSE": pytest.approx(0.05)}


def test_px4_stores_param_set_bytes_whatever_type_the_sender_declared():
    link = VirtualLink(configured_options("px4"))
    as_int = struct.unpack("<f", struct.pack("<i", 11))[0]
    link.send(link.mav.param_set_encode(1, 1, b"EKF2_EV_CTRL", as_int, INT32))
    assert link.model.params.stored("EKF2_EV_CTRL") == 11
    link.send(link.mav.param_set_encode(1, 1, b"EKF2_EV_CTRL", 3.0, REAL32))
    assert link.model.params.stored("EKF2_EV_CTRL") == 1077936128  # 3.0f read as an int
    answer = read(link, "EKF2_EV_CTRL")
    assert struct.unpack("<i", struct.pack("<f", answer.param_value))[0] == 1077936128


def test_reboot_required_parameter_takes_effect_after_a_reboot_which_keeps_it():
    link = VirtualLink(SimOptions())
    link.send(link.mav.param_set_encode(1, 1, b"VISO_TYPE", 2, REAL32))
    assert read(link, "VISO_TYPE").param_value == 2  # stored at once
    assert not link.model.visual_odom.enabled  # the running firmware still has type 0
    assert link.command(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == \
        mavlink2.MAV_RESULT_ACCEPTED
    link.advance(0.2)
    assert link.model.down and read(link, "VISO_TYPE") is None  # silent while rebooting
    link.advance(1.0)
    assert link.model.visual_odom.enabled and read(link, "VISO_TYPE").param_value == 2


def test_reboot_is_refused_while_armed():
    link = VirtualLink(SimOptions())
    link.advance(0.1)
    assert link.model.arm(link.now) == mavlink2.MAV_RESULT_ACCEPTED  # STABILIZE, no vision
    assert link.command(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == \
        mavlink2.MAV_RESULT_FAILED


def test_configured_set_is_what_check_autopilot_apply_leaves():
    opt = configured_options(by_parameter=True)
    link = VirtualLink(opt)
    for name, value in {"VISO_TYPE": 2, "EK3_SRC1_POSXY": 6, "GPS1_TYPE": 0,
                        "MAV3_EXTRA1": 50, "SERIAL2_BAUD": 921}.items():
        assert read(link, name).param_value == value, name
    old = VirtualLink(configured_options(release=Release.COPTER_4_5, by_parameter=True))
    assert read(old, "GPS_TYPE").param_value == 0 and read(old, "SR2_EXTRA1").param_value == 50
