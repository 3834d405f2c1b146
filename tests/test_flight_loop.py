"""CI's closed-loop flight: the simulated ArduCopter takes off, holds and lands on the estimate
our tracker and fusion send it, on the virtual clock, with the camera rendered where it truly
is (a short mission at 320x240: a few tens of seconds).

The autopilot arms only once vision arrives (ArduPilot's VisOdom pre-arm check), so the service
must publish while standing on the ground (issue 26): a run that sent nothing fails here."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from daemon.config import Config
from sim.autopilot.records import EventKind
from sim.flight.frames_csv import COLUMNS, write_flight_frames
from sim.flight.loop import ClosedLoop
from sim.flight.mission import parse_mission
from sim.flight.report import flight_report
from sim.flight.runner import Outcome
from sim.flight.scores import score

MISSION = parse_mission({"world": "hover-down", "steps": [
    {"wait": "vision", "timeout_s": 10}, {"wait": "position"}, {"mode": "GUIDED"},
    {"arm": True}, {"takeoff": 1.0}, {"mode": "LOITER"}, {"hold": 1.0}, {"land": True}]})


@pytest.fixture(scope="module")
def flight():
    run = ClosedLoop(MISSION, Config(), seed=0, size=(320, 240)).run()
    assert run.sent, "the service sent nothing on the ground, so the autopilot cannot arm"
    return run


def test_the_mission_is_flown_to_the_end(flight):
    assert [r.outcome for r in flight.steps] == [Outcome.DONE] * len(MISSION.steps)
    height = flight.truth.positions[0, 2] - flight.truth.positions[:, 2]
    assert height.max() > 0.9  # it really climbed (truth), to about the 1 m asked
    assert abs(height[-1]) < 0.02  # and stands on its gear again
    assert not flight.record.of(EventKind.FAILSAFE)


def test_the_autopilot_flies_on_what_we_sent(flight):
    extnav = flight.record.first(EventKind.EXTNAV_STARTED)
    takeoff = next(r for r in flight.steps if r.step.action.value == "takeoff")
    assert extnav is not None and extnav.t < takeoff.started
    # every frame after the first estimate went out, and reached the autopilot 38 ms after
    # its capture (35 ms tracker and fusion, 3 ms link)
    first = next(i for i, r in enumerate(flight.rows) if r["sent"])
    assert all(r["sent"] for r in flight.rows[first:])
    latency = [m.t_arrival - m.fields["time_usec"] / 1e6 for m in flight.sent]
    assert np.allclose(latency, 0.038, atol=1e-6)
    # while it used them, the autopilot's position followed ours within their covariance
    ours = {round(m.fields["time_usec"] / 1e6 - flight.timing.our_clock_s, 2):
            np.array([m.fields[k] for k in "xy"]) for m in flight.sent}
    gaps = [np.linalg.norm(e.position[:2] - ours[round(e.t, 2)]) for e in
            flight.record.estimates if e.using_vision and round(e.t, 2) in ours]
    assert gaps and np.median(gaps) < 0.1


def test_the_report_leads_with_the_verdict(flight):
    report = flight_report(flight, score(flight))
    assert report["verdict"].split(":")[0] in ("READY for LOITER", "NOT READY")
    assert report["armed"] and report["steps_done"] == len(MISSION.steps)
    assert report["suggested_viso_delay_ms"] == pytest.approx(38.0, abs=0.01)  # whole us stamps
    assert report["expert"]["messages_received"] == len(flight.sent)


def test_the_frames_csv_has_a_row_per_frame_with_the_truth(flight, tmp_path):
    path = tmp_path / "frames.csv"
    write_flight_frames(path, flight)
    rows = list(csv.DictReader(path.open()))
    assert tuple(rows[0]) == COLUMNS and len(rows) == len(flight.rows)
    sent = [r for r in rows if r["sent"] == "1"]
    assert all(r["x"] != "nan" for r in sent)
    assert all(r["x"] == "nan" for r in rows if r["sent"] == "0")
    # what we sent is where the vehicle was, within its covariance, in the truth's frame
    gaps = [np.hypot(float(r["x"]) - float(r["true_x"]), float(r["y"]) - float(r["true_y"]))
            for r in sent]
    stds = [np.hypot(float(r["std_x"]), float(r["std_y"])) for r in sent]
    assert np.median(gaps) < 0.1 and np.median(gaps) < 3 * np.median(stds)
    tracked = [r for r in rows if r["map_x"] != "nan"]
    assert tracked and all(int(r["inliers"]) <= int(r["matches"]) for r in tracked)
