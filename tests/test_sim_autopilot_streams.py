"""What the simulated autopilots stream on the companion's port, and how the companion gets more:
stream-rate parameters (after a reboot), MAV_CMD_SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM,
MAV_CMD_REQUEST_MESSAGE (virtual clock)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import Release, SimOptions, configured_options
from sim.autopilot.virtual import VirtualLink

SET_INTERVAL = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL


def counts(link: VirtualLink, since: float) -> dict[str, int]:
    out: dict[str, int] = {}
    for t, msg in link.heard:
        if t >= since:
            out[msg.get_type()] = out.get(msg.get_type(), 0) + 1
    return out

def counts_after_reboot(link: VirtualLink) -> dict[str, int]:
    """Reboot, wait out the downtime, and count one second of what the new boot sends."""
    link.command(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
    link.advance(1.0)
    since = link.now
    link.advance(1.0)
    return counts(link, since)



def test_fresh_ardupilot_sends_only_heartbeat_and_a_timesync_every_10_s():
    link = VirtualLink(SimOptions())
    link.advance(21.0)
    seen = counts(link, 0)
    assert seen.pop("HEARTBEAT") == pytest.approx(21, abs=1)
    assert seen.pop("TIMESYNC") == 2
    assert set(seen) <= {"STATUSTEXT"}  # the EKF's start messages
    assert all(m.ts1 % 1000 == 1 for m in link.of("TIMESYNC"))  # micros * 1000 + system id


def test_stream_rate_parameters_work_after_a_reboot():
    link = VirtualLink(SimOptions())
    link.send(link.mav.param_set_encode(1, 1, b"MAV3_EXTRA1", 20, 9))
    link.send(link.mav.param_set_encode(1, 1, b"MAV3_RAW_SENS", 10, 9))
    link.advance(2.0)
    assert "ATTITUDE" not in counts(link, 0)  # reboot required
    link.command(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
    link.advance(1.0)
    since = link.now
    link.advance(2.0)
    seen = counts(link, since)
    assert seen["ATTITUDE"] == pytest.approx(40, abs=2)
    # RAW_SENS is RAW_IMU, SCALED_IMU2 and SCALED_PRESSURE; not SCALED_IMU
    for name in ("RAW_IMU", "SCALED_IMU2", "SCALED_PRESSURE"):
        assert seen[name] == pytest.approx(20, abs=2), name
    assert "SCALED_IMU" not in seen and "DISTANCE_SENSOR" not in seen


def test_old_release_names_its_stream_rates_srn():
    link = VirtualLink(SimOptions(release=Release.COPTER_4_5, params={"SR2_EXTRA3": 5}))
    link.advance(2.0)
    seen = counts(link, 0)
    assert seen["DISTANCE_SENSOR"] == pytest.approx(10, abs=1)
    assert seen["EKF_STATUS_REPORT"] == pytest.approx(10, abs=1)


def test_set_message_interval_per_message_is_acked_and_lost_at_reboot():
    link = VirtualLink(SimOptions())
    assert link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 20000) == \
        mavlink2.MAV_RESULT_ACCEPTED
    assert link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_SCALED_IMU, 10000) == \
        mavlink2.MAV_RESULT_ACCEPTED
    assert link.command(SET_INTERVAL, 12345, 10000) == mavlink2.MAV_RESULT_FAILED
    since = link.now
    link.advance(1.0)
    seen = counts(link, since)
    assert seen["ATTITUDE"] == pytest.approx(50, abs=2)
    assert seen["SCALED_IMU"] == pytest.approx(100, abs=2)
    assert "ATTITUDE" not in counts_after_reboot(link)


def test_set_message_interval_zero_is_the_group_rate_and_minus_one_stops():
    link = VirtualLink(SimOptions(params={"MAV3_EXTRA1": 4}))
    link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 100000)
    link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 0)
    since = link.now
    link.advance(1.0)
    assert counts(link, since)["ATTITUDE"] == pytest.approx(4, abs=1)
    link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, -1)
    since = link.now + 0.01
    link.advance(1.0)
    assert "ATTITUDE" not in counts(link, since)


def test_request_data_stream_sets_the_group_in_ram_only():
    link = VirtualLink(SimOptions())
    link.send(link.mav.request_data_stream_encode(1, 1, 10, 25, 1))  # EXTRA1 at 25 Hz
    since = link.now
    link.advance(1.0)
    assert counts(link, since)["ATTITUDE"] == pytest.approx(25, abs=1)
    link.send(link.mav.param_request_read_encode(1, 1, b"MAV3_EXTRA1", -1))
    assert link.of("PARAM_VALUE")[-1].param_value == 25  # readable until the reboot
    assert "ATTITUDE" not in counts_after_reboot(link)


def test_request_data_stream_ignored_with_mav_options_bit_2():
    link = VirtualLink(SimOptions(params={"MAV3_OPTIONS": 4}))
    link.send(link.mav.request_data_stream_encode(1, 1, 10, 25, 1))
    link.advance(1.0)
    assert "ATTITUDE" not in counts(link, 0)


def test_request_message_sends_once():
    link = VirtualLink(SimOptions())
    assert link.command(mavlink2.MAV_CMD_REQUEST_MESSAGE,
                        mavlink2.MAVLINK_MSG_ID_ATTITUDE) == mavlink2.MAV_RESULT_ACCEPTED
    link.advance(1.0)
    assert counts(link, 0)["ATTITUDE"] == 1


def test_px4_telem2_is_silent_until_an_instance_is_configured_there():
    link = VirtualLink(SimOptions(flavour="px4"))
    link.advance(2.0)
    assert link.heard == []
    link = VirtualLink(configured_options("px4", by_parameter=True))
    link.advance(2.0)
    seen = counts(link, 0)
    # Onboard mode's own streams
    assert seen["TIMESYNC"] == pytest.approx(20, abs=1)
    assert seen["HIGHRES_IMU"] == pytest.approx(100, abs=2)
    assert seen["ATTITUDE"] == pytest.approx(200, abs=3)
    assert seen["DISTANCE_SENSOR"] == pytest.approx(20, abs=1)


def test_px4_ignores_request_data_stream_and_honours_set_message_interval():
    link = VirtualLink(configured_options("px4", by_parameter=True))
    link.send(link.mav.request_data_stream_encode(1, 1, 10, 2, 1))
    assert link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_HEARTBEAT, 100000) == \
        mavlink2.MAV_RESULT_FAILED
    assert link.command(SET_INTERVAL, mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU, 5000) == \
        mavlink2.MAV_RESULT_ACCEPTED
    since = link.now
    link.advance(1.0)
    seen = counts(link, since)
    assert seen["ATTITUDE"] == pytest.approx(100, abs=2)  # not 2 Hz
    assert seen["HIGHRES_IMU"] == pytest.approx(200, abs=3)
