"""The IMU and barometer streams fused are the ones that stream steadily, not the first message
seen (daemon/fusion/source_choice.py)."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon.config import MountingConfig
from daemon.fusion.estimator import FusionEstimator
from daemon.fusion.sensors import IMU_PRIORITY
from daemon.fusion.source_choice import SourceChoice
from sim import fusion_sim as fh


def offers(choice: SourceChoice, samples: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """The (t, source) samples the choice fuses."""
    return [(t, s) for t, s in sorted(samples) if choice.offer(s, t)]


def series(source: str, t0: float, t1: float, hz: float) -> list[tuple[float, str]]:
    return [(float(t), source) for t in np.arange(t0, t1, 1.0 / hz)]


def test_one_stray_message_of_a_preferred_kind_changes_nothing():
    choice = SourceChoice("imu", IMU_PRIORITY)
    scaled = series("SCALED_IMU", 0.0, 10.0, 50)
    fused = offers(choice, [*scaled, (5.001, "HIGHRES_IMU"), (7.5, "HIGHRES_IMU")])
    assert {s for _, s in fused} == {"SCALED_IMU"}
    assert len(fused) == len(scaled)  # the first stream from its first sample
    assert choice.switches == 1


def test_a_preferred_stream_takes_over_once_steady_and_hands_back_when_it_stops():
    choice = SourceChoice("imu", IMU_PRIORITY)
    samples = [*series("SCALED_IMU", 0.0, 20.0, 50), *series("HIGHRES_IMU", 5.0, 10.0, 100)]
    fused = offers(choice, samples)
    highres = [t for t, s in fused if s == "HIGHRES_IMU"]
    assert 5.0 < highres[0] < 5.1 and highres[-1] > 9.98  # steady after 5 samples
    scaled_while_highres = [t for t, s in fused if s == "SCALED_IMU" and 5.1 < t < 10.0]
    assert scaled_while_highres == []  # one stream at a time
    back = [t for t, s in fused if s == "SCALED_IMU" and t >= 10.0]
    assert back[0] - 10.0 <= 1.05  # the stopped stream is given up within MAX_GAP_S
    assert choice.current == "SCALED_IMU" and choice.switches == 3


def test_estimator_keeps_its_imu_when_one_highres_imu_arrives():
    flight = fh.simulate(truth=fh.survey_flight(climb_m=3.0, leg_m=6.0, legs=1), seed=7)
    messages = list(flight.messages)
    k = len(messages) // 4
    arrival, _ = messages[k]
    stray = mavlink2.MAVLink_highres_imu_message(
        int((arrival - fh.BOOT_OFFSET) * 1e6), 3.0, 0.0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
        0b111)
    messages.insert(k + 1, (arrival, stray))
    estimator = FusionEstimator(fh.fusion_config(), MountingConfig())
    out = fh.run(fh.Flight(flight.truth, messages, flight.frames), estimator)
    clean = fh.run(flight, FusionEstimator(fh.fusion_config(), MountingConfig()))
    assert estimator.sources["imu"] == "SCALED_IMU"
    assert estimator._choices["imu"].switches == 1
    published = sum(e is not None for _, e in out)
    assert published == sum(e is not None for _, e in clean) and published > 0
    last = [e for _, e in out if e is not None][-1]
    last_clean = [e for _, e in clean if e is not None][-1]
    assert np.allclose(last.position, last_clean.position, atol=0.05)
