"""`sdvl fly --realtime`: the real service against the simulated ArduCopter in its own process
on the wall clock. Asserts only what does not depend on the machine's speed: the mission's
steps are run by the autopilot's process, the service's camera gets frames rendered at the
vehicle's pose, and every process started is gone afterwards."""

from __future__ import annotations

import multiprocessing

import numpy as np

from daemon.config import Config
from sim.flight.mission import parse_mission
from sim.flight.realtime import TruthShare, fly_realtime
from sim.flight.runner import Outcome


def test_truth_crosses_processes_whole():
    share = TruthShare()
    T = np.arange(16.0).reshape(4, 4)
    share.write(2.5, T)
    t, read = TruthShare(share.array).read()
    assert t == 2.5 and np.array_equal(read, T)


def test_realtime_flight_runs_the_mission_beside_a_busy_process():
    mission = parse_mission({"world": "hover-down",
                             "steps": [{"wait": "autopilot"}, {"hold": 2.0}]})
    run = fly_realtime(mission, Config(), 0, (96, 72), (), load=1)
    assert run.realtime and run.load == 1
    assert [r.outcome for r in run.steps] == [Outcome.DONE, Outcome.DONE]
    assert run.rows and run.offered >= len(run.rows)  # the service tracked rendered frames
    assert all(0.0 <= r["t_source"] <= run.truth.t[-1] + 1.0 for r in run.rows)
    assert np.allclose(run.truth.positions[-1][:2], 0.0, atol=1e-6)  # still on its gear
    assert run.record.statustexts  # the autopilot's own record came back from its process
    assert multiprocessing.active_children() == []
