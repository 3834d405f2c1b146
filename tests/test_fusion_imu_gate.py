"""What the fusion keeps from its filter: a message repeating a stamp (repeats.py), an IMU spike
(imu_gate.py) and a single wrong IMU sample of any size (imu_hampel.py); a real change of
acceleration passes, and an IMU stream that keeps failing is dropped and taken back."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon.fusion.imu_gate import READMIT_S, SPIKE_FLOOR, ImuGate
from daemon.fusion.imu_hampel import ImuHampel
from daemon.fusion.repeats import Repeats

HOVER = np.array([0.0, 0.0, -9.81])


def feed(gate: ImuGate, accels, t0: float = 0.0, hz: float = 50.0, source: str = "SCALED_IMU"):
    """Admit each acceleration in turn at `hz`; the verdicts."""
    return [gate.admit(source, t0 + k / hz, a) for k, a in enumerate(accels)]


def noisy(n: int, seed: int = 0, mean: np.ndarray = HOVER) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return list(mean + rng.normal(0.0, 1.5, (n, 3)))  # a vibrating vehicle's filtered IMU


def test_a_vibrating_stream_passes_whole():
    gate = ImuGate()
    assert all(feed(gate, noisy(500)))
    assert gate.rejected == 0


def test_a_spike_is_rejected_and_a_lasting_change_passes_within_half_the_window():
    gate = ImuGate()
    accels = noisy(100)
    accels[50] = HOVER + np.array([0.0, 0.0, 2 * SPIKE_FLOOR])  # one corrupt sample
    step = HOVER + np.array([1.5 * SPIKE_FLOOR, 0.0, 0.0])  # a hard manoeuvre that lasts
    verdicts = feed(gate, accels + [step] * 20)
    assert verdicts[50] is False and all(verdicts[:50]) and all(verdicts[51:100])
    assert all(verdicts[104:])  # the median has moved: the new acceleration is real


def test_a_repeated_stamp_is_a_copy_per_message_kind_and_sensor():
    repeats = Repeats()
    pressure = mavlink2.MAVLink_scaled_pressure_message(1000, 1013.0, 0.0, 2000, 0)
    assert not repeats.seen(pressure, 1.0) and repeats.seen(pressure, 1.0)
    assert not repeats.seen(pressure, 0.98)  # late, not a copy: the filter replays it
    imu = mavlink2.MAVLink_scaled_imu_message(1000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0)
    assert not repeats.seen(imu, 1.0)  # another kind's own stamps
    ranges = [mavlink2.MAVLink_distance_sensor_message(1000, 10, 1200, 150, 0, k, 25, 0)
              for k in (0, 1)]
    assert not repeats.seen(ranges[0], 1.0) and not repeats.seen(ranges[1], 1.0)  # two sensors
    assert repeats.count == 1


def test_a_failing_stream_is_dropped_said_and_taken_back_when_clean():
    said: list[str] = []
    gate = ImuGate(said.append)
    rng = np.random.default_rng(1)
    accels = noisy(300)
    for k in range(100, 200, 3):  # a third of the samples corrupt for 2 s
        accels[k] = HOVER + rng.uniform(-1, 1, 3) * 10 * SPIKE_FLOOR
    verdicts = feed(gate, accels + noisy(int(READMIT_S * 50) + 50, seed=2), t0=0.0)
    assert len(said) == 2 and "dropped" in said[0] and "used again" in said[1]
    dropped = [k for k, ok in enumerate(verdicts) if not ok and k >= 200]
    assert dropped and dropped[-1] < 200 + READMIT_S * 50 + 10  # clean samples not used
    assert verdicts[-1] is True


def judge(samples, order=None, hz: float = 50.0):
    """Push (index order) samples of one stream at `hz`; {time index: specific force fused}."""
    hampel, out = ImuHampel(keep_s=1.0), {}
    for k in order if order is not None else range(len(samples)):
        judged = hampel.push("SCALED_IMU", k / hz, samples[k])
        if judged is not None:
            out[round(judged[0] * hz)] = judged[1]
    return out


def test_hampel_removes_one_wrong_sample_of_any_size_and_keeps_the_rest_as_they_are():
    rng = np.random.default_rng(3)
    clean = [HOVER + rng.normal(0.0, 0.05, 3) for _ in range(60)]
    corrupt = list(clean)
    corrupt[20] = HOVER + np.array([0.0, 0.0, 9.81])  # zacc 0: passes the 2 g spike gate
    corrupt[40] = HOVER + np.array([3.0, 0.0, 0.0])
    out = judge(corrupt)
    assert sorted(out) == list(range(1, 59))  # each once its successor came; not the ends
    for k in (20, 40):
        assert np.linalg.norm(out[k] - HOVER) < 0.2
    assert all(np.array_equal(out[k], clean[k]) for k in out if k not in (20, 40))


def test_hampel_passes_a_step_of_thrust_and_judges_a_reordered_sample_between_its_neighbours():
    step = [HOVER] * 10 + [HOVER + np.array([0.0, 0.0, -8.0])] * 10
    out = judge(step)
    assert np.array_equal(out[10], step[10]) and np.array_equal(out[11], step[11])
    order = list(range(20))
    order[5], order[6] = 6, 5  # sample 5 arrives after 6
    assert sorted(judge(step, order)) == list(range(1, 19))
