"""Scoring a closed-loop flight in truth: the hold drift, the corner errors in the autopilot's
frame moved to the world's, height steps and failsafes from the autopilot's record, and the
verdict line built from them."""

from __future__ import annotations

import numpy as np
import pytest

from sim.autopilot.records import (
    AutopilotRecord,
    EstimateSample,
    Event,
    EventKind,
    Severity,
    StatusText,
)
from sim.flight.flight_run import FlightRun, Timing
from sim.flight.mission import parse_mission
from sim.flight.report import flight_report, verdict
from sim.flight.runner import Outcome, StepResult
from sim.flight.scores import (
    FlightScores,
    HeightErrors,
    HoldScore,
    corner_scores,
    failsafes,
    frame_offset,
    height_errors,
    height_steps,
    hold_scores,
    score,
)
from sim.flight.seeds import format_seed_table, summarize_flights
from sim.trajectory import Trajectory

MISSION = parse_mission({"steps": [{"arm": True}, {"takeoff": 3}, {"mode": "LOITER"},
                                   {"hold": 10}, {"goto": [2, 0]}]})
SHIFT = np.array([5.0, -1.0, -0.15])  # the world's position of the autopilot's origin


def _truth() -> Trajectory:
    """On the ground until 1 s, 3 m up from 2 s; during the hold (3-13 s) a wander north that
    reaches 0.2 m at 8 s and 0.05 m up; then 2.1 m north by 20 s."""
    t = np.arange(0.0, 25.0, 0.02)
    p = np.zeros((t.size, 3))
    p[:, 2] = -3.0 * np.clip(t - 1.0, 0, 1)
    p[:, 0] = np.where((t > 3) & (t < 13), 0.2 * np.sin(np.pi * (t - 3) / 10) ** 2, 0.0)
    p[(t > 3) & (t < 13), 2] -= 0.05 * np.sin(np.pi * (t[(t > 3) & (t < 13)] - 3) / 10)
    p[:, 0] += 2.1 * np.clip((t - 14) / 6, 0, 1)
    quat = np.tile([0, 0, 0, 1.0], (t.size, 1))
    return Trajectory(t, p + SHIFT, quat)


def _run(record: AutopilotRecord | None = None) -> FlightRun:
    arm, takeoff, mode, hold, goto = MISSION.steps
    home = np.array([0.0, 0.0, 0.0])
    results = [StepResult(arm, 0.5, 0.6, Outcome.DONE, home=home),
               StepResult(takeoff, 0.6, 2.5, Outcome.DONE),
               StepResult(mode, 2.9, 3.0, Outcome.DONE),
               StepResult(hold, 3.0, 13.0, Outcome.DONE),
               StepResult(goto, 13.0, 22.0, Outcome.DONE, target=np.array([2.0, 0.0, -3.0]),
                          home=home, arrived=20.0)]
    return FlightRun(MISSION, 0, (), Timing(), _truth(), results, [], [],
                     record or AutopilotRecord(), 40.0)


def test_hold_drift_is_the_largest_distance_from_the_start_of_the_hold():
    (hold,) = hold_scores(_run())
    assert hold.mode == "LOITER" and hold.seconds == 10.0
    assert hold.drift_xy_m == pytest.approx(0.2, abs=1e-3)
    assert hold.drift_z_m == pytest.approx(0.05, abs=1e-3)


def test_corner_error_is_measured_in_the_world_from_the_arming_point():
    run = _run()
    assert np.allclose(frame_offset(run), SHIFT)
    (corner,) = corner_scores(run)
    assert corner.target == (2.0, 0.0, 3.0)
    assert corner.error_xy_m == pytest.approx(0.1, abs=1e-6)  # flew 2.1 m north for 2 m
    assert corner.error_z_m == pytest.approx(0.0, abs=1e-6)


def test_height_errors_compare_heights_from_the_arming_point_while_airborne():
    # the autopilot thinks it is 0.5 m lower than it is from 8 s on; ground time is not counted
    estimates = [EstimateSample(t, np.array([0.0, 0.0, -0.4 - 3.0 * np.clip(t - 1, 0, 1)
                                             + (0.5 if t >= 8 else 0.0)]), np.zeros(3), True)
                 for t in np.arange(0.0, 25.0, 0.1)]
    errors = height_errors(_run(AutopilotRecord(estimates=estimates)))
    assert errors.autopilot_m == pytest.approx(0.55, abs=1e-6)  # and the hold's 5 cm climb
    assert errors.ours_m is None  # no vision message in this record


def test_height_steps_and_failsafes_come_from_the_autopilots_record():
    record = AutopilotRecord(
        statustexts=[StatusText(4.0, Severity.CRITICAL, "EKF variance"),
                     StatusText(4.0, Severity.CRITICAL, "EKF Failsafe: changed to LAND Mode"),
                     StatusText(1.0, Severity.INFO, "EKF3 IMU0 is using external nav data")],
        events=[Event(0.2, EventKind.HEIGHT_RESET, "external nav start", -0.76)])
    run = _run(record)
    (step,) = height_steps(run)
    assert step.step_m == pytest.approx(0.76) and step.why == "external nav start"
    assert failsafes(run) == ["4.0 s EKF variance", "4.0 s EKF Failsafe: changed to LAND Mode"]


def _scores(**changes) -> FlightScores:
    base = {"steps_done": 4, "failed": None, "armed": True, "takeoff_s": 1.0, "extnav_s": 0.5,
            "holds": [HoldScore("LOITER", 30.0, 0.12, 0.03)], "corners": [],
            "heights": HeightErrors(0.05, 0.04), "height_steps": [],
            "failsafes": [], "latency_ms": [38.0] * 10, "suggested_delay_ms": 38.0,
            "viso_delay_ms": 40.0, "expert": {}}
    return FlightScores(**{**base, **changes})


def test_verdict_ready_names_the_drift_and_the_delay_check():
    line, loiter, guided = verdict(_scores())
    assert line == "READY for LOITER: drift 0.12 m; VISO_DELAY_MS 40 fits the 38 ms measured"
    assert loiter and not guided


def test_verdict_says_what_to_change():
    drift = verdict(_scores(holds=[HoldScore("LOITER", 30.0, 0.45, 0.0)],
                            suggested_delay_ms=71.6))[0]
    assert drift == ("NOT READY: LOITER drifted 0.45 m (limit 0.3 m); set VISO_DELAY_MS 72 "
                     "(it is 40.0)")
    late = verdict(_scores(extnav_s=8.0))[0]
    assert "used our estimate only 7.0 s after take-off" in late
    assert verdict(_scores(failsafes=["4.0 s EKF variance"]))[0].startswith(
        "NOT READY: failsafe: 4.0 s EKF variance")


def test_verdict_says_whose_height_wandered():
    line, loiter, _ = verdict(_scores(holds=[HoldScore("LOITER", 30.0, 0.1, 0.6)],
                                      heights=HeightErrors(0.62, 0.08)))
    assert loiter and line.startswith("READY for LOITER: drift 0.10 m; its height wandered "
                                      "0.60 m: the autopilot's own height was off by 0.62 m in "
                                      "flight, ours by 0.08 m -> it flies on its barometer")
    ours = verdict(_scores(holds=[HoldScore("LOITER", 30.0, 0.1, 0.6)],
                           heights=HeightErrors(0.1, 0.62)))[0]
    assert "ours by 0.62 m" in ours and "barometer" not in ours  # no advice about its baro


def test_seed_table_has_a_line_per_seed_and_the_worst_over_them():
    reports = [flight_report(_run(), score(_run())) for _ in range(2)]
    reports[1].update(hold_drift_m=0.4, ready_loiter=False, ready_guided=False,
                      verdict="NOT READY: LOITER drifted 0.40 m (limit 0.3 m)")
    summary = summarize_flights(reports)
    assert summary["runs"] == 2 and summary["hold_drift_m_max"] == 0.4
    assert summary["armed"] == 2 and summary["ready_loiter"] == 1
    text = format_seed_table([3, 7], reports, summary)
    lines = text.splitlines()
    assert lines[3].split()[:4] == ["3", "READY-G", "yes", "n/a"]  # no extnav in the record
    assert lines[4].split()[:2] == ["7", "NOT-READY"] and lines[4].split()[4] == "0.40"
    assert "ready for LOITER 1, for GUIDED 1, armed 2" in text
    assert "worst: LOITER drift 0.400 m, corner 0.100 m" in text
    assert lines[-1] == "     7  NOT READY: LOITER drifted 0.40 m (limit 0.3 m)"
