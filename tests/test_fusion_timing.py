"""Time handling: late and out-of-order autopilot messages, the TIMESYNC offset, stale frames."""

from __future__ import annotations

import numpy as np
import pytest

from daemon.config import MountingConfig
from daemon.fusion.config import FusionConfig
from daemon.fusion.estimator import FusionEstimator
from daemon.fusion.sensors import remote_time
from daemon.fusion.state import LOG_SCALE, POS, VEL
from sim import fusion_sim as fh
from sim.replay.fusion_scores import turned_about_down
from vo.result import FrameResult


@pytest.fixture(scope="module")
def flight() -> fh.Flight:
    return fh.simulate(truth=fh.survey_flight(legs=1), seed=5)


def final_state(flight: fh.Flight, offset: float | None = None) -> tuple:
    estimator = FusionEstimator(FusionConfig(), MountingConfig())
    estimator.set_clock_offset(offset)
    out = fh.run(flight, estimator)
    return estimator, out


def with_messages(flight: fh.Flight, messages: list) -> fh.Flight:
    return fh.Flight(flight.truth, messages, flight.frames)


@pytest.fixture(scope="module")
def on_time(flight: fh.Flight) -> tuple:
    """The flight with every message on time and the clock offset known: what the tests below
    compare with (read, never fed more)."""
    return final_state(flight, offset=fh.BOOT_OFFSET)


def test_late_messages_are_fused_by_replaying_the_filter(flight: fh.Flight, on_time) -> None:
    on_time, _ = on_time
    rng = np.random.default_rng(2)
    late = [(arrival + (0.3 if rng.random() < 0.2 else 0.0), msg)
            for arrival, msg in flight.messages]
    late.sort(key=lambda item: item[0])
    delayed, out = final_state(with_messages(flight, late), offset=fh.BOOT_OFFSET)
    assert delayed.timeline.replays > 10
    assert delayed.timeline.dropped_late < 5  # only those from before the first frame
    # the map's anchor (state.py) is bookkeeping: it moves when the filter re-anchors
    navigation = np.r_[POS, VEL, LOG_SCALE]
    assert delayed.filter.x[navigation] == pytest.approx(on_time.filter.x[navigation], abs=0.05)
    assert fh.score(flight, out).position_pct < 3.0


def test_arrival_order_does_not_matter_within_a_frame(flight: fh.Flight, on_time) -> None:
    in_order, _ = on_time
    swapped = list(flight.messages)  # stamped ones: an unstamped one's arrival is its time
    for k in range(0, len(swapped) - 1, 2):
        if all(remote_time(m) is not None for _, m in swapped[k:k + 2]):
            swapped[k], swapped[k + 1] = swapped[k + 1], swapped[k]
    shuffled, _ = final_state(with_messages(flight, swapped), offset=fh.BOOT_OFFSET)
    # equal up to decisions taken at a threshold (a gate, the take-off's first sample) that a
    # sample arriving one frame later can tip: a few centimetres after 30 m
    assert shuffled.filter.x == pytest.approx(in_order.filter.x, abs=0.05)


def test_messages_older_than_the_history_are_dropped_and_counted(flight: fh.Flight) -> None:
    stale = [(arrival + (1.5 if k % 50 == 0 else 0.0), msg)
             for k, (arrival, msg) in enumerate(flight.messages)]
    stale.sort(key=lambda item: item[0])
    estimator, out = final_state(with_messages(flight, stale))
    assert estimator.timeline.dropped_late + estimator.dropped_stamps > 0
    assert fh.score(flight, out).position_pct < 3.0


def test_timesync_offset_and_arrival_estimate_agree(flight: fh.Flight, on_time) -> None:
    _, estimated = final_state(flight)
    _, synced = on_time
    a, b = fh.score(flight, estimated), fh.score(flight, synced)
    assert a.position_pct < 3.0 and b.position_pct < 3.0
    assert abs(a.position_rmse_m - b.position_rmse_m) < 0.1


def test_a_frame_older_than_the_last_one_is_not_published(flight: fh.Flight) -> None:
    """Never an estimate for an earlier moment; a lost frame carries the filter on (dead
    reckoning), less sure than before."""
    estimator, out = final_state(flight)
    t_last, last = out[-1]
    result = flight.frames[-2][1]
    assert estimator.on_frame(result, t_last - 0.5) is None
    carried = estimator.on_frame(FrameResult(0.0, None, "lost"), t_last + 0.1)
    assert carried is not None and carried.t_capture == t_last + 0.1
    assert np.trace(carried.pose_covariance[:3, :3]) >= np.trace(last.pose_covariance[:3, :3])


def test_a_stalled_tracker_is_bridged_on_the_imu(flight: fh.Flight) -> None:
    """No frame for 0.6 s in the survey (the tracker busy): the bridge's estimates carry the
    vehicle on with the IMU, their covariance growing and covering the error, and the frames
    after the stall continue without a reset."""
    estimator = FusionEstimator(FusionConfig(), MountingConfig())
    stall = (12.0, 12.6)  # flight time, s
    clock = {"now": 0.0}
    estimator.now = lambda: clock["now"]
    k, bridged, after = 0, [], []
    messages = flight.messages
    for ready, result, t_capture in flight.frames:
        t = t_capture - fh.BOOT_OFFSET
        if stall[0] <= t < stall[1]:
            while k < len(messages) and messages[k][0] <= ready:
                clock["now"] = messages[k][0]
                estimator.on_autopilot_message(messages[k][1])
                k += 1
            if round(t * 30) % 2 == 0:  # the service asks every other frame period
                bridged.append((t, estimator.bridge(t_capture)))
            continue
        while k < len(messages) and messages[k][0] <= ready:
            clock["now"] = messages[k][0]
            estimator.on_autopilot_message(messages[k][1])
            k += 1
        estimate = estimator.on_frame(result, t_capture)
        if t >= stall[1] and estimate is not None:
            after.append(estimate)
    assert bridged and all(e is not None for _, e in bridged)
    stds = [np.sqrt(np.trace(e.pose_covariance[:3, :3])) for _, e in bridged]
    assert stds[-1] > stds[0]
    for t, e in bridged:
        moved = flight.truth.p[flight.truth.at(t)] - flight.truth.p[0]
        error = e.position - turned_about_down(moved[None], flight.compass_bias_deg)[0]
        assert error @ np.linalg.solve(e.pose_covariance[:3, :3], error) < 16.3  # 3 dof 99.9%
    assert after and after[0].reset_counter == bridged[-1][1].reset_counter == 0
