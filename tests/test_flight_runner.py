"""The mission runner as a ground station against the simulated ArduCopter (virtual clock):
what it waits for, what it sends, how a refusal ends the mission with the autopilot's own words,
and the verdict a user reads then."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sim.flight.autopilot_side import AutopilotSide
from sim.flight.flight_run import Timing
from sim.flight.mission import parse_mission
from sim.flight.report import verdict
from sim.flight.runner import Outcome
from sim.flight.scores import FlightScores, HeightErrors
from sim.flight.world import FlightWorld

STEP_S = 0.0025


@pytest.fixture(scope="module")
def world() -> FlightWorld:
    return FlightWorld.of_preset("hover-down", 0, (64, 48), textures="procedural")


class PerfectCompanion:
    """The truth as ODOMETRY at 30 Hz (reset_counter 0, 2 cm), and a 1 Hz HEARTBEAT."""

    def __init__(self) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=197)
        self.next_odometry = self.next_heartbeat = 0.0

    def messages(self, now: float, T: np.ndarray) -> list[bytes]:
        out = []
        if now >= self.next_heartbeat:
            self.next_heartbeat += 1.0
            out.append(self.mav.heartbeat_encode(18, 8, 0, 0, 4))
        if now >= self.next_odometry:
            self.next_odometry += 1 / 30
            x, y, z, w = _quat(T[:3, :3])
            cov = [np.nan] * 21
            cov[0] = cov[6] = cov[11] = 4e-4
            cov[15] = cov[18] = cov[20] = 1e-4
            out.append(self.mav.odometry_encode(
                int(now * 1e6), 20, 12, *T[:3, 3], [w, x, y, z], 0, 0, 0, 0, 0, 0, cov,
                [np.nan] * 21, 0, 3, 100))
        data = []
        for msg in out:
            data.append(msg.pack(self.mav))
            self.mav.seq = (self.mav.seq + 1) % 256
        return data


def _quat(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()


def fly(world: FlightWorld, steps: list[dict], companion: PerfectCompanion | None = None
        ) -> AutopilotSide:
    side = AutopilotSide(parse_mission({"steps": steps}), world, 0, Timing())
    now = 0.0
    while not side.done:
        now += STEP_S
        if companion is not None:
            for data in companion.messages(now, side.T_ned_body):
                side.from_companion(data, now)
        side.step(now)
    return side


def _scores(side: AutopilotSide) -> FlightScores:
    failed = side.runner.failed
    return FlightScores(sum(r.outcome is Outcome.DONE for r in side.runner.results), failed,
                        False, None, None, [], [], HeightErrors(None, None), [], [], [], None,
                        40.0, {})


def test_without_vision_the_wait_times_out_and_says_so(world):
    side = fly(world, [{"wait": "vision", "timeout_s": 2}])
    result = side.runner.results[0]
    assert result.outcome is Outcome.TIMEOUT and 2.0 <= result.ended <= 2.1
    assert result.detail == "no vision yet"
    line, loiter, guided = verdict(_scores(side))
    assert line.startswith("NOT READY: step 1 (wait for vision) timed out")
    assert "no vision messages on the link" in line and not (loiter or guided)


def test_arming_without_vision_is_refused_in_the_autopilots_words(world):
    side = fly(world, [{"arm": True, "timeout_s": 2.5}])
    result = side.runner.results[0]
    assert result.outcome is Outcome.TIMEOUT
    assert "PreArm: VisOdom: not healthy" in result.detail
    acks = [r for _, c, r in side.gcs.acks if c == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM]
    assert len(acks) >= 2 and set(acks) == {mavlink2.MAV_RESULT_FAILED}  # retried each second
    assert "the service must publish while on the ground" in verdict(_scores(side))[0]


def test_guided_without_a_position_fails_at_once(world):
    side = fly(world, [{"mode": "GUIDED"}])
    result = side.runner.results[0]
    assert result.outcome is Outcome.FAILED and result.ended < 0.2
    assert "Mode change to GUIDED failed: requires position" in result.detail


def test_with_vision_it_waits_sets_guided_and_arms_at_home(world):
    steps = [{"wait": "vision"}, {"wait": "position"}, {"wait": "extnav"},
             {"mode": "GUIDED"}, {"arm": True}, {"hold": 1.0}]
    side = fly(world, steps, PerfectCompanion())
    results = side.runner.results
    assert [r.outcome for r in results] == [Outcome.DONE] * len(steps)
    assert side.gcs.armed and side.gcs.custom_mode == 4
    assert results[0].ended < 1.0  # 10 messages within a second of the first
    home = results[4].home  # the autopilot's own position; arming re-zeroes its height
    assert np.allclose(home[:2], side.model.vehicle.T_ned_body[:2, 3], atol=0.05)
    assert abs(home[2]) < 0.05
    assert results[5].ended - results[5].started == pytest.approx(1.0, abs=0.01)
