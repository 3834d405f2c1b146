"""Fuzzed inputs never make the fusion publish NaN or infinity, and spikes do not move it."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from daemon.config import MountingConfig
from daemon.fusion.estimator import FusionEstimator
from sim import fusion_sim as fh
from vo.result import FrameResult

FLIGHT = fh.simulate(truth=fh.survey_flight(climb_m=3.0, leg_m=6.0, legs=1), seed=7)
FIELDS = {"ATTITUDE": ("roll", "pitch", "yaw", "time_boot_ms"),
          "SCALED_IMU": ("xacc", "zacc", "time_boot_ms"),
          "DISTANCE_SENSOR": ("current_distance", "time_boot_ms"),
          "SCALED_PRESSURE": ("press_abs", "time_boot_ms"),
          "HEARTBEAT": ("base_mode", "autopilot", "type"),
          "EXTENDED_SYS_STATE": ("landed_state",)}
BAD = [math.nan, math.inf, -math.inf, 1e12, -1e12, 0.0, 32767, -32768, 2**32 - 1]


def finite(e) -> bool:
    arrays = (e.position, e.R_local_body, e.velocity_local, e.velocity_body, e.angular_rate,
              e.pose_covariance, e.velocity_covariance)
    return all(np.all(np.isfinite(a)) for a in arrays) and 1 <= e.quality <= 100


def corrupt_frame(result: FrameResult, kind: int) -> FrameResult:
    out = copy.copy(result)
    if result.T_w_c is None:
        return out
    T = result.T_w_c.copy()
    if kind == 0:
        T[0, 3] = math.nan
    elif kind == 1:
        T[:3, 3] += 1e6
    elif kind == 2:
        out.covariance = np.full((6, 6), math.inf)
    elif kind == 3:
        out.covariance = -np.eye(6)
    else:
        out.new_segment = True
    out.T_w_c = T
    return out


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_fuzzed_messages_and_frames_never_give_nan(data: st.DataObject) -> None:
    messages = [(a, copy.copy(m)) for a, m in FLIGHT.messages]
    for _ in range(data.draw(st.integers(0, 40))):
        k = data.draw(st.integers(0, len(messages) - 1))
        arrival, msg = messages[k]
        name = data.draw(st.sampled_from(FIELDS[msg.get_type()]))
        setattr(msg, name, data.draw(st.sampled_from(BAD)))
        messages[k] = (arrival + data.draw(st.sampled_from([0.0, 0.5, -0.5, 5.0])), msg)
    gap = data.draw(st.tuples(st.floats(0, 20), st.floats(0, 3)))
    messages = [(a, m) for a, m in messages
                if not gap[0] <= a - fh.BOOT_OFFSET < gap[0] + gap[1]]
    messages.sort(key=lambda item: item[0])
    frames = list(FLIGHT.frames)
    for _ in range(data.draw(st.integers(0, 10))):
        k = data.draw(st.integers(0, len(frames) - 1))
        ready, result, t_capture = frames[k]
        frames[k] = (ready, corrupt_frame(result, data.draw(st.integers(0, 4))), t_capture)
    estimator = FusionEstimator(fh.fusion_config(), MountingConfig())
    out = fh.run(fh.Flight(FLIGHT.truth, messages, frames), estimator)
    assert all(finite(e) for _, e in out if e is not None)


def test_spikes_and_gaps_do_not_move_the_estimate() -> None:
    rng = np.random.default_rng(11)
    messages = []
    for arrival, msg in FLIGHT.messages:
        msg = copy.copy(msg)
        if msg.get_type() == "SCALED_PRESSURE" and rng.random() < 0.1:
            msg.press_abs -= 5.0  # a 40 m baro spike
        elif msg.get_type() == "DISTANCE_SENSOR" and rng.random() < 0.1:
            msg.current_distance = 30  # a bird under the rangefinder
        if not 12.0 <= arrival - fh.BOOT_OFFSET < 13.0:  # a one-second link gap
            messages.append((arrival, msg))
    estimator = FusionEstimator(fh.fusion_config(), MountingConfig())
    out = fh.run(fh.Flight(FLIGHT.truth, messages, FLIGHT.frames), estimator)
    clean = fh.run(FLIGHT, FusionEstimator(fh.fusion_config(), MountingConfig()))
    spiked, reference = fh.score(FLIGHT, out), fh.score(FLIGHT, clean)
    print(f"\nspiked {spiked}\nclean {reference}")
    assert spiked.published > 0.8 * reference.published
    assert spiked.position_rmse_m < reference.position_rmse_m + 0.1


@pytest.mark.parametrize("kind", ["no attitude", "nothing"])
def test_without_attitude_nothing_is_published(kind: str) -> None:
    messages = [] if kind == "nothing" else [
        (a, m) for a, m in FLIGHT.messages if m.get_type() != "ATTITUDE"]
    texts: list[str] = []
    estimator = FusionEstimator(fh.fusion_config(), MountingConfig(),
                                report=texts.append)
    out = fh.run(fh.Flight(FLIGHT.truth, messages, FLIGHT.frames), estimator)
    assert all(e is None for _, e in out)
    assert texts and "ATTITUDE" in texts[0]
