"""The simulated ArduPilot's vision path: AP_VisualOdom's backends and EKF3's external-nav rules,
each against a companion that gets it right and one that gets it wrong (virtual clock)."""

from __future__ import annotations

import numpy as np
import pytest
from autopilot_helpers import Companion, height_jump, takeoff
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from sim.autopilot import configured_options
from sim.autopilot.gcs_vision import JitterCorrection, PoseSample, covariance_errors
from sim.autopilot.nav_filter import NavFilter
from sim.autopilot.param_store import ParamStore
from sim.autopilot.params import ardupilot_specs
from sim.autopilot.records import EventKind
from sim.autopilot.virtual import VirtualLink
from sim.autopilot.visual_odom import Ahrs, VisualOdom

HOVER_AT_S = 5.0  # takeoff(): on the ground 2 s, climbing 2 s, at 3.4 m from 4 s


def hovering(viso_type: int, **changes) -> VirtualLink:
    """ArduCopter set up for vision, its vehicle hovering at 3.4 m, no vision yet."""
    link = VirtualLink(configured_options(viso_type=viso_type, requested={},
                                          trajectory=takeoff(), **changes))
    link.advance(HOVER_AT_S)
    return link


def test_voxl_first_message_with_reset_counter_1_puts_the_height_to_zero():
    """autopilot-interface.md (e) 3: type 3 re-aligns the first position to (0,0,0)."""
    link = hovering(3)
    Companion(link, reset_counter=1).fly(2.0)
    texts = link.texts()
    assert "VisOdom: reset" in texts
    assert "EKF3 IMU0 initial pos NED = 0.0,0.0,0.0 (m)" in texts
    start = link.model.record.first(EventKind.HEIGHT_RESET)
    assert start.value == pytest.approx(-3.4, abs=0.3)  # the height snapped down


def test_voxl_with_reset_counter_0_keeps_the_height():
    link = hovering(3)
    Companion(link, reset_counter=0).fly(2.0)
    assert "VisOdom: reset" not in link.texts()
    assert "EKF3 IMU0 initial pos NED = 0.0,0.0,-3.4 (m)" in link.texts()
    assert height_jump(link, HOVER_AT_S) < 0.1


def test_ext_nav_start_resets_the_height_to_its_z_even_with_baro_height():
    """(e) 4: a vision frame whose z origin is 0.76 m above the autopilot's puts a step in the
    height when EKF3 starts using it, with EK3_SRC1_POSZ = 1 (baro)."""
    link = hovering(2)
    assert link.model.params.get("EK3_SRC1_POSZ") == 1
    Companion(link, origin=np.array([0.0, 0.0, -0.76])).fly(2.0)
    assert "EKF3 IMU0 is using external nav data" in link.texts()
    assert link.model.record.first(EventKind.HEIGHT_RESET).value == pytest.approx(-0.76, abs=0.2)
    assert height_jump(link, HOVER_AT_S) > 0.5


def test_type_2_ignores_the_second_after_a_reset_counter_change():
    """(e) 5: the first message's reset_counter 1 differs from the 0 the autopilot starts
    with: a second of data is ignored before EKF3 uses any."""
    link = hovering(2)
    Companion(link, reset_counter=1).fly(2.0)
    ignored = link.model.record.of(EventKind.VISION_IGNORED)
    started = link.model.record.first(EventKind.EXTNAV_STARTED)
    assert 28 <= len(ignored) <= 32  # 1 s of 30 Hz
    assert started.t - ignored[0].t == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize(("viso_type", "reset_size"), [(1, 2.0), (3, 0.0)])
def test_reset_counter_change_resets_the_position(viso_type, reset_size):
    """A 2 m jump flagged by reset_counter: type 1 passes it to EKF3 (ResetPositionNE), type 3
    re-aligns the new frame onto the last position (no jump)."""
    link = hovering(viso_type)
    companion = Companion(link)
    companion.fly(1.0)
    companion.origin, companion.reset_counter = np.array([-2.0, 0.0, 0.0]), 1
    companion.fly(1.0)
    reset = link.model.record.first(EventKind.POSITION_RESET)
    assert reset is not None and reset.value == pytest.approx(reset_size, abs=0.15)


def test_ext_nav_timeout_stops_aiding_and_position_status():
    link = hovering(2)
    Companion(link).fly(1.0)
    link.send(link.mav.command_long_encode(1, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                           ardupilotmega.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 100000,
                                           0, 0, 0, 0, 0))
    link.advance(1.0)
    assert link.of("EKF_STATUS_REPORT")[-1].flags & 16  # POS_HORIZ_ABS
    link.advance(7.0)
    assert not link.of("EKF_STATUS_REPORT")[-1].flags & 16
    assert "EKF3 IMU0 stopped aiding" not in link.texts()
    link.advance(8.0)
    assert "EKF3 IMU0 stopped aiding" in link.texts()


def test_local_position_follows_vision_with_the_companions_latency_in_viso_delay():
    """Vision sent 100 ms after capture, stamped at capture: the jitter correction makes the
    least-delayed message 'now', so only VISO_DELAY_MS = 100 puts it at the right time."""
    errors = []
    for delay_ms in (0, 100):
        link = VirtualLink(configured_options(
            requested={"LOCAL_POSITION_NED": 10}, trajectory=takeoff(north_speed=2.0),
            param_overrides={"VISO_DELAY_MS": delay_ms, "VISO_POS_M_NSE": 0.1}))
        link.advance(HOVER_AT_S)
        companion = Companion(link)

        def late(now: float, companion: Companion = companion) -> None:
            companion.send(now - 0.1)  # the pose of 100 ms ago
        link.advance(4.0, 1 / 30, late)
        north = [m.x for m in link.of("LOCAL_POSITION_NED", link.now - 1.0)]
        truth = [link.model.vehicle.state(link.model.uptime(t))["position"][0]
                 for t, m in link.heard if m.get_type() == "LOCAL_POSITION_NED"
                 and t >= link.now - 1.0]
        errors.append(np.mean(np.abs(np.subtract(north, truth))))
    assert errors[1] < 0.5 * errors[0]


def test_arming_without_origin_resets_the_height_datum():
    link = VirtualLink(configured_options(requested={}, trajectory=takeoff(ground_s=10)))
    link.advance(1.0)
    Companion(link).fly(1.0)
    link.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert link.model.record.of(EventKind.HEIGHT_RESET)[-1].detail == "height datum reset"


def test_covariance_to_errors_and_the_parameter_floors():
    """posErr = cbrt(sum of squared variances): 1 cm sigma is 0.003 m, then clamped to
    VISO_POS_M_NSE; an unknown covariance (NaN) is the floor."""
    cov = [0.0] * 21
    cov[0] = cov[6] = cov[11] = 1e-4
    cov[15] = cov[18] = cov[20] = 0.25
    pos_err, ang_err = covariance_errors(cov)
    assert pos_err == pytest.approx((3e-8) ** (1 / 3)) and ang_err == pytest.approx(
        (3 * 0.0625) ** (1 / 3))
    params = ParamStore(ardupilot_specs(configured_options().release),
                        {"VISO_TYPE": 1, "VISO_POS_M_NSE": 0.15})
    odom = VisualOdom(params, Ahrs(), lambda *_: None)
    sample = PoseSample(0.0, np.zeros(3), Rotation.identity(), pos_err, ang_err, 0, 0)
    out = odom.handle_pose(sample, 0.0)
    assert out.pos_err == pytest.approx(0.15) and out.ang_err == pytest.approx(ang_err)
    assert covariance_errors([np.nan] * 21) == (0.0, 0.0)


def test_quality_below_viso_qual_min_is_not_used_but_keeps_it_healthy():
    link = hovering(2, param_overrides={"VISO_QUAL_MIN": 50})
    companion = Companion(link)
    link.advance(2.0, 1 / 30, lambda now: link.odometry(
        np.zeros(3), Rotation.identity(), np.zeros(3), quality=40))
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is None
    assert link.model.visual_odom.healthy(link.now)
    companion.fly(1.0)
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is not None


def test_jitter_correction_takes_the_least_delayed_message_as_arrival():
    jitter = JitterCorrection()
    arrivals = [10.0 + 0.03 * k + (0.02 if k % 3 else 0.0) for k in range(10)]
    corrected = [jitter.correct(0.03 * k, a) for k, a in enumerate(arrivals)]
    assert corrected[-1] == pytest.approx(10.0 + 0.27)  # offset of the fastest, not the mean
    assert jitter.correct(0.0, 20.0) == pytest.approx(19.5)  # at most 500 ms in the past


def test_viso_pos_lever_arm_is_taken_off_and_viso_scale_multiplies():
    link = hovering(1, param_overrides={"VISO_POS_X": 0.3, "VISO_POS_Z": 0.1})
    Companion(link, lever=np.array([0.3, 0.0, 0.1])).fly(2.0)
    assert link.model.ekf.filter.position == pytest.approx([0.0, 0.0, -3.4], abs=0.05)
    params = ParamStore(ardupilot_specs(configured_options().release),
                        {"VISO_TYPE": 1, "VISO_SCALE": 2.0})
    odom = VisualOdom(params, Ahrs(), lambda *_: None)
    sample = PoseSample(0.0, np.array([1.0, 2.0, 3.0]), Rotation.identity(), 0.1, 0.1, 0, 0)
    assert odom.handle_pose(sample, 0.0).position == pytest.approx([2.0, 4.0, 6.0])


def test_viso_orient_turns_the_attitude_only():
    params = ParamStore(ardupilot_specs(configured_options().release),
                        {"VISO_TYPE": 2, "VISO_ORIENT": 25})
    odom = VisualOdom(params, Ahrs(), lambda *_: None)  # AHRS yaw not there: no alignment
    down = Rotation.from_euler("y", 270, degrees=True)  # a camera looking down, level vehicle
    sample = PoseSample(0.0, np.array([1.0, 2.0, 3.0]), down, 0.1, 0.1, 0, 0)
    out = odom.handle_pose(sample, 0.0)
    assert out.position == pytest.approx([1.0, 2.0, 3.0])
    assert out.attitude.magnitude() == pytest.approx(0.0, abs=1e-9)


def test_a_delayed_measurement_meets_the_state_of_its_own_time():
    """NavFilter.state_at interpolates between kept steps, keeps corrections made since, and
    answers the oldest kept for anything older than its 0.5 s history."""
    nav = NavFilter(0.35)
    for k in range(1, 101):  # 1 m/s^2 north for 2 s at 50 Hz, from rest
        nav.predict(np.array([1.0, 0.0, 0.0]), 0.02, k * 0.02)
    assert nav.state_at(1.91)[1][0] == pytest.approx(1.91)  # between two steps
    nav.reset([0], [10.0], 0.01, 0)  # a position reset of +8 m moves the past with it
    assert nav.state_at(1.9)[0][0] == pytest.approx(1.9 ** 2 / 2 + 8.0)
    assert nav.state_at(0.1)[1][0] == pytest.approx(1.5)  # the oldest kept, not beyond
