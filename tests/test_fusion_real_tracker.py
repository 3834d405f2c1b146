"""Fusion on the real SDVL tracker's output: the first 200 frames of the synthetic `hover-down`
flight (take-off from 1.5 m) tracked by vo.Tracker, the flight's recorded autopilot sensors fed
alongside, as the lockstep replay does (sim/replay/lockstep.py).

The real tracker's position errors are several times the covariance it reports and follow its
tilt errors; before the filter modelled that, it published for 1.5 s, then rejected every frame
and re-aligned for good (issue 7). Numbers are printed (run with -s)."""

from __future__ import annotations

import numpy as np
import pytest

from daemon.config import Config
from daemon.fusion.estimator import FusionEstimator
from sim.datasets import open_sequence
from sim.replay.flight import drone_config, sensor_streams, vehicle_trajectory
from sim.replay.fusion_scores import compass_bias_deg, turned_about_down
from sim.replay.lockstep import BOOT_CLOCK, OUR_CLOCK, autopilot_messages
from vo.config import TrackerConfig
from vo.tracker import Tracker

FRAMES = 200
RESULT_DELAY = 0.03  # capture -> tracker result


@pytest.fixture(scope="module")
def fused():
    sequence = open_sequence("hover-down")
    tracker = Tracker(sequence.camera, TrackerConfig(), threaded=False)
    results = [tracker.process(image, t) for t, image in sequence.frames(FRAMES)]
    tracker.close()
    config = drone_config(Config(), sequence)
    flight = vehicle_trajectory(sequence.groundtruth, config)
    messages = autopilot_messages(sequence, flight, sensor_streams("ardupilot", flight),
                                  results[-1].t + 1.0)
    clock = [0.0]
    estimator = FusionEstimator(config.fusion, config.mounting,
                                now=lambda: clock[0])
    estimator.set_clock_offset(OUR_CLOCK - BOOT_CLOCK)
    estimates, k = [], 0
    for result in results:
        t_capture = result.t + OUR_CLOCK
        while k < len(messages) and messages[k][0] <= t_capture + RESULT_DELAY:
            clock[0] = messages[k][0]
            estimator.on_autopilot_message(messages[k][1])
            k += 1
        clock[0] = t_capture + RESULT_DELAY
        estimates.append((result, estimator.on_frame(result, t_capture)))
    return estimates, flight, estimator, compass_bias_deg(sequence)


def test_publishes_steadily_after_convergence(fused) -> None:
    estimates, _flight, estimator, _bias = fused
    tracked = [e for r, e in estimates if r.has_pose]
    first = next(i for i, e in enumerate(tracked) if e is not None)
    published = sum(e is not None for e in tracked[first:])
    first_t = next(r.t for r, e in estimates if e is not None)
    print(f"\nfirst estimate at {first_t:.2f} s; published {published} of "
          f"{len(tracked) - first} tracked frames since; reset_counter {estimator.reset_counter}")
    assert first_t <= 5.0  # the take-off starts at once: scale converged within 5 s of it
    assert published >= 0.9 * (len(tracked) - first)
    assert estimator.reset_counter == 0


def _errors_and_nees(fused) -> tuple[float, float, bool]:
    """(ATE after the start alignment, position NEES per dof in the autopilot's heading frame,
    all outputs finite)."""
    estimates, flight, _, bias = fused
    pairs = [(r.t, e) for r, e in estimates if e is not None]
    t = np.array([t for t, _ in pairs])
    position = np.array([e.position for _, e in pairs])
    truth = np.column_stack([np.interp(t, flight.t, flight.positions[:, i]) for i in range(3)])
    error = position - (truth + position[0] - truth[0])
    ate = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    in_frame = position - position[0] - turned_about_down(truth - truth[0], bias)
    nees = float(np.mean([x @ np.linalg.solve(e.pose_covariance[:3, :3], x)
                          for x, (_, e) in zip(in_frame, pairs, strict=True)])) / 3
    finite = all(np.all(np.isfinite(e.position)) and np.all(np.isfinite(e.pose_covariance))
                 for _, e in pairs)
    print(f"\nATE {ate:.3f} m after the start alignment over {len(pairs)} estimates, "
          f"position NEES per dof {nees:.2f}")
    return ate, nees, finite


def test_accuracy_and_never_overconfident(fused) -> None:
    ate, nees, finite = _errors_and_nees(fused)
    assert finite
    assert ate <= 0.35
    assert nees <= 2.0  # a covariance smaller than the errors would mislead the autopilot


def test_consistent_not_overcautious(fused) -> None:
    """0.22 with the flight's recorded sensors and datasheet (0.13 when the sensors were exact
    and the filter was told the hardware defaults). These 200 frames are the take-off, where
    the filter allows for the sideways wander of a climb (vo_drift_climb_m_per_sqrt_m) that this
    seed hardly shows and hover-down seeds 6 and 8 show at 0.29 and 0.06 m; over whole flights
    hover-down's NEES is 0.17-2.42 (seeds 0-9), so one window is held only to a floor."""
    _ate, nees, _finite = _errors_and_nees(fused)
    assert nees >= 0.1
