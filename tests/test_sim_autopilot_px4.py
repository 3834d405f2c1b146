"""The simulated PX4's external-vision path: EKF2_EV_CTRL, the height reference, ev_reset, the
200 ms / 400 ms EV timing, EKF2_EV_QMIN, the noise floors and TIMESYNC-mapped stamps (virtual
clock)."""

from __future__ import annotations

import numpy as np
import pytest
from autopilot_helpers import Companion, height_jump, takeoff
from scipy.spatial.transform import Rotation

from sim.autopilot import configured_options
from sim.autopilot.ekf2 import Ekf2
from sim.autopilot.param_store import ParamStore
from sim.autopilot.params import px4_specs
from sim.autopilot.px4 import CONVERGENCE_WINDOW, Timesync
from sim.autopilot.records import AutopilotRecord, EventKind
from sim.autopilot.virtual import VirtualLink

HOVER_AT_S = 5.0


def hovering(**overrides: float) -> VirtualLink:
    link = VirtualLink(configured_options("px4", requested={}, trajectory=takeoff(),
                                          param_overrides=overrides))
    link.advance(HOVER_AT_S)
    return link


def test_ev_start_resets_the_horizontal_position_to_vision():
    link = hovering()
    Companion(link, origin=np.array([-1.0, 2.0, 0.0])).fly(1.0)
    start = link.model.record.first(EventKind.EXTNAV_STARTED)
    assert start.detail == "reset_pos_to_vision"
    assert link.model.ekf.filter.position[:2] == pytest.approx([1.0, -2.0], abs=0.05)
    assert link.model.ekf.local_position_valid()


@pytest.mark.parametrize(("hgt_ref", "stepped"), [(3, True), (0, False)])
def test_vision_height_reference_resets_the_altitude_baro_does_not(hgt_ref, stepped):
    """Vision frame z origin 0.76 m above the EKF's: with EKF2_HGT_REF vision the altitude is
    reset to it (a step), with the barometer as reference an offset absorbs it."""
    link = hovering(EKF2_HGT_REF=hgt_ref)
    Companion(link, origin=np.array([0.0, 0.0, -0.76])).fly(2.0)
    assert (height_jump(link, HOVER_AT_S) > 0.5) == stepped
    assert bool(link.model.record.of(EventKind.HEIGHT_RESET)) == stepped


def test_ev_ctrl_zero_fuses_nothing():
    link = hovering(EKF2_EV_CTRL=0)
    Companion(link).fly(1.0)
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is None
    assert not link.model.ekf.local_position_valid()


def test_reset_counter_change_is_an_ev_reset():
    link = hovering()
    companion = Companion(link)
    companion.fly(1.0)
    companion.origin, companion.reset_counter = np.array([-2.0, 0.0, 0.0]), 1
    companion.fly(0.5)
    reset = link.model.record.first(EventKind.POSITION_RESET)
    assert reset is not None and reset.value == pytest.approx(2.0, abs=0.1)


def test_ev_needs_samples_within_200_ms_and_stops_after_400_ms():
    link = hovering()
    Companion(link).fly(2.0, rate_hz=4.0)  # 250 ms apart: never starts
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is None
    Companion(link).fly(1.0, rate_hz=10.0)
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is not None
    link.advance(0.25)
    assert link.model.ekf.active["pos"]
    link.advance(0.2)
    assert not link.model.ekf.active["pos"]
    assert link.model.record.first(EventKind.EXTNAV_STOPPED).detail == "vision data stopped"


def test_ev_qmin_gates_the_start():
    link = hovering(EKF2_EV_QMIN=50)
    level = Rotation.identity()
    link.advance(1.0, 1 / 30,
                 lambda now: link.odometry(np.zeros(3), level, np.zeros(3), quality=40))
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is None
    Companion(link).fly(0.5)  # quality 100
    assert link.model.record.first(EventKind.EXTNAV_STARTED) is not None


def test_noise_mode_floors_the_message_variance():
    params = ParamStore(px4_specs(), {"EKF2_EVP_NOISE": 0.2})
    ekf = Ekf2(params, AutopilotRecord(), 0.0, 0.0)
    assert ekf._floor(np.array([0.01, 0.09, 1.0]), 0.2) == pytest.approx([0.04, 0.09, 1.0])
    assert ekf._floor(np.full(3, np.nan), 0.2) == pytest.approx([0.04] * 3)
    params.set("EKF2_EV_NOISE_MD", 1)
    assert ekf._floor(np.array([1.0, 1.0, 1.0]), 0.2) == pytest.approx([0.04] * 3)


def test_vision_stamps_are_arrival_times_until_timesync_has_500_replies():
    sync = Timesync()
    assert sync.sync_stamp(5.0, 7.0) == 7.0
    for k in range(CONVERGENCE_WINDOW):
        now = 10.0 + 0.1 * k
        sync.update(now + 0.004, now - 3.0 + 0.002, now)  # remote clock 3 s behind, 4 ms RTT
    assert sync.converged
    assert sync.sync_stamp(5.0, 9.0) == pytest.approx(8.0, abs=1e-3)
    slow = Timesync()
    slow.update(10.05, 7.02, 10.0)  # a 50 ms round trip is not used
    assert slow.samples == 0


def test_px4_answers_timesync_and_counts_the_companions_replies():
    link = hovering()
    requests = link.of("TIMESYNC")
    assert requests and all(m.tc1 == 0 for m in requests)  # Onboard mode asks at 10 Hz
    answered: set[int] = set()

    def answer(now: float) -> None:
        request = link.of("TIMESYNC")[-1]
        if request.ts1 not in answered:  # straight away, as a companion on a fast link does
            answered.add(request.ts1)
            link.send(link.mav.timesync_encode(int(now * 1e9), request.ts1))
    link.advance(1.0, 0.005, answer)
    assert link.model.timesync.samples >= 9
