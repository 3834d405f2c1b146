"""The simulated ArduCopter flies (virtual clock): a ground station arms it with default
ARMING_CHECK once vision arrives, takes off in GUIDED, holds LOITER, flies a GUIDED square, lands
and disarms; losing vision in flight lands it through the EKF failsafe; VISO_TYPE 3 with a first
reset_counter of 1 flies it into the ground, as a real ArduCopter did (autopilot-interface.md
(e) 3)."""

from __future__ import annotations

import numpy as np
import pytest
from flight_helpers import ACCEPTED, ALT_HOLD, ARM, GUIDED, LAND, LOITER, STABILIZE, Flight
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import SimOptions
from sim.autopilot.dynamics import Dynamics
from sim.autopilot.records import EventKind
from sim.autopilot.simulator import make_model

FAILED = mavlink2.MAV_RESULT_FAILED


def test_stands_on_the_ground_where_it_was_put():
    flight = Flight(dynamics=Dynamics(north_m=2.0, east_m=-1.0, yaw_deg=90.0,
                                      ground_down_m=0.4))
    flight.link.advance(2.0)
    T = flight.vehicle.T_ned_body
    gear = flight.vehicle.dynamics.airframe.gear_height_m
    assert T[:3, 3] == pytest.approx([2.0, -1.0, 0.4 - gear], abs=1e-9)
    assert T[:3, 0] == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)  # nose east
    assert flight.vehicle.on_ground and not flight.vehicle.velocity_ned.any()


def test_takes_off_in_guided_and_holds_loiter():
    flight = Flight(seed=1)
    flight.take_off(3.0)
    assert flight.height() == pytest.approx(3.0, abs=0.3)
    assert flight.mode(LOITER) == ACCEPTED
    flight.fly(2.0)
    start = flight.truth()
    drift, touchdown = [], []
    for _ in range(10):
        flight.fly(1.0)
        drift.append(np.linalg.norm(flight.truth()[:2] - start[:2]))
        touchdown.append(flight.model.ekf.touchdown_expected)
    assert max(drift) < 0.1  # a perfect companion: the hold is the controllers' own
    # a hover demands no descent: the baro is fused as in flight (a float residue of the
    # shaped climb rate read as descent flagged touchdown, and the height wandered)
    assert not any(touchdown)


def test_flies_a_guided_square_and_lands_and_disarms():
    flight = Flight(seed=2)
    flight.take_off(3.0)
    corners = [(2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)]
    for north, east in corners:
        flight.goto(north, east, -3.0)
        flight.fly(5.0)
        estimate = flight.model.ekf.filter.position
        assert estimate[:2] == pytest.approx([north, east], abs=0.1)
        assert flight.truth()[:2] == pytest.approx([north, east], abs=0.15)
    assert flight.mode(LAND) == ACCEPTED
    flight.fly(12.0)
    assert not flight.model.armed
    assert flight.model.record.of(EventKind.DISARMED)[-1].detail == "landed"
    touchdown = flight.vehicle.body.touchdown_speeds[0]
    assert 0.3 < touchdown < 0.7  # LAND_SPEED 0.5 m/s


def test_losing_vision_in_loiter_lands_through_the_ekf_failsafe():
    flight = Flight(seed=3)
    flight.take_off(2.0, settle_s=6.0)
    flight.mode(LOITER)
    flight.fly(1.0)
    flight.vision = False
    flight.fly(24.0)
    texts = flight.link.texts()
    assert "EKF variance" in texts and "EKF Failsafe: changed to LAND Mode" in texts
    assert flight.vehicle.on_ground and not flight.model.armed
    assert max(flight.vehicle.body.touchdown_speeds) < 1.0


@pytest.mark.parametrize(("reset_counter", "hits_ground"), [(1, True), (0, False)])
def test_voxl_first_reset_counter_1_flies_it_into_the_ground(reset_counter, hits_ground):
    """(e) 3: climbed in ALT_HOLD without vision (ARMING_CHECK relaxed, as there), vision then
    starts at about 3.4 m: with reset_counter 1 VISO_TYPE 3 re-aligns the first position to
    (0,0,0), EKF3's height snaps to 0, the barometer pulls it back up and the altitude hold
    descends the vehicle until it hits the ground; with 0 nothing happens. The companion's
    first covariance is a new map's (1 m): the height snaps with that variance."""
    flight = Flight(viso_type=3, position_var=1.0, param_overrides={"ARMING_CHECK": 0})
    flight.vision = False
    flight.fly(1.0)
    assert flight.mode(ALT_HOLD) == ACCEPTED and flight.command(ARM, 1) == ACCEPTED
    while flight.height() < 3.0:
        flight.sticks(throttle=1800)
        flight.fly(0.1)
    flight.sticks(throttle=1500)
    flight.fly(2.0)
    assert 3.0 < flight.height() < 4.5
    flight.companion.reset_counter = reset_counter
    flight.vision = True
    flight.fly(6.0)
    touched = bool(flight.vehicle.body.touchdown_speeds)
    assert touched is hits_ground
    assert ("VisOdom: reset" in flight.link.texts()) is hits_ground


def test_alt_hold_neutral_sticks_stays_down_then_holds_after_a_climb():
    flight = Flight(param_overrides={"ARMING_CHECK": 0})
    flight.vision = False
    flight.fly(1.0)
    flight.mode(ALT_HOLD)
    flight.command(ARM, 1)
    flight.fly(3.0)
    assert flight.vehicle.on_ground  # mid-stick is a zero climb rate
    for _ in range(15):
        flight.sticks(throttle=1900)
        flight.fly(0.1)
    flight.sticks(throttle=1500)
    flight.fly(3.0)
    held = flight.height()
    flight.fly(3.0)
    assert held > 1.0 and flight.height() == pytest.approx(held, abs=0.2)


def test_stabilize_mid_stick_gives_the_hover_throttle_level():
    """Mid-stick is MOT_THST_HOVER (0.35 by default, under this airframe's true 0.39): it
    stays on the ground, level, until the stick goes up."""
    flight = Flight(param_overrides={"ARMING_CHECK": 0})
    flight.vision = False
    flight.fly(1.0)
    assert flight.mode(STABILIZE) == ACCEPTED and flight.command(ARM, 1) == ACCEPTED
    flight.fly(2.0)
    assert flight.vehicle.on_ground
    flight.sticks(throttle=1700)
    flight.fly(1.0)
    assert not flight.vehicle.on_ground
    tilt = np.degrees(np.arccos(flight.vehicle.T_ned_body[2, 2]))
    assert tilt < 3.0


def test_gcs_commands_follow_copters_rules():
    """NAV_TAKEOFF needs GUIDED, armed and landed; position targets only count in GUIDED; RC
    overrides only from the ground station's system id."""
    flight = Flight()
    flight.fly(2.0)
    takeoff = (mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)
    assert flight.command(*takeoff) == FAILED  # disarmed
    flight.sticks(throttle=1000)  # a pilot arms STABILIZE with the throttle down
    assert flight.command(ARM, 1) == ACCEPTED
    assert flight.command(*takeoff) == FAILED  # STABILIZE has no user takeoff
    flight.goto(5.0, 0.0, -3.0)  # ignored: not GUIDED
    flight.sticks(throttle=1900, system=1)  # ignored: not the GCS
    flight.fly(2.0)
    assert flight.vehicle.on_ground
    flight.mode(GUIDED)
    assert flight.command(*takeoff) == ACCEPTED
    flight.fly(3.0)
    assert flight.command(ARM, 0) == FAILED  # in the air


def test_a_flight_is_deterministic_for_a_seed():
    paths = []
    for _ in range(2):
        flight = Flight(seed=5)
        flight.take_off(2.0, settle_s=3.0)
        paths.append(flight.truth())
    assert paths[0] == pytest.approx(paths[1], abs=1e-12)


def test_only_arducopter_flies():
    with pytest.raises(ValueError, match="only the simulated ArduCopter flies"):
        make_model(SimOptions(flavour="px4", dynamics=Dynamics()), None, 0.0)


def test_the_vehicle_is_where_it_is_between_the_estimators_steps():
    """A camera frame taken between two 50 Hz estimator steps sees the vehicle at that instant
    (its 400 Hz physics run as time passes), not where it was at the last step."""
    flight = Flight(seed=2)
    flight.take_off(3.0, settle_s=0.0)
    flight.fly(3.0)  # climbing
    model = flight.model
    t0 = model._last_step + 0.02 + 1e-6  # the next estimator step
    model.step(t0)
    heights = []
    for k in range(8):  # the fast loops of one estimator step, one at a time
        model.step(t0 + (k + 0.5) / 400.0)
        heights.append(-flight.truth()[2])
    climbs = np.diff(heights)
    assert np.all(climbs > 0) and np.ptp(climbs) < 0.5 * climbs.mean()
