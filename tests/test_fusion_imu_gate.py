"""What the fusion keeps from its filter: a message repeating a stamp (repeats.py) and an IMU
spike (imu_gate.py); a real change of acceleration and a touch-down's jolt pass, and an IMU
stream that keeps failing is dropped and taken back."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from daemon.fusion.imu_gate import SPIKE_FLOOR, ImuGate
from daemon.fusion.repeats import Repeats
from daemon.fusion.stream_health import READMIT_S
from sim.autopilot.imu import Lowpass2

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


def _touch_down(speed: float, phase: int) -> list[np.ndarray]:
    """A hover's filtered IMU at 50 Hz with the gear stopping a descent of `speed` (m/s) over
    20 ms: the jolt through ArduPilot's 20 Hz 2-pole filter at 400 Hz (sim.autopilot.imu),
    sampled every 8th loop from `phase`."""
    lowpass = Lowpass2(20.0, 400.0)
    jolt = np.array([0.0, 0.0, speed / 0.02])
    loops = [lowpass.apply(HOVER - (jolt if 400 <= k < 408 else 0.0)) for k in range(800)]
    return [a + n for a, n in zip(loops[phase::8], noisy(100, mean=np.zeros(3)), strict=True)]


@pytest.mark.parametrize("speed", [0.5, 1.0, 1.5])
def test_a_touch_down_jolt_passes_while_descending_at_every_phase(speed):
    # missing the jolt, the filter keeps descending past the ground, and LAND (its climb rate
    # ours) never detects the landing; the same samples while hovering are corrupt
    spiked = 0
    for phase in range(8):
        samples = _touch_down(speed, phase)
        plain = feed(ImuGate(), samples)
        spiked += not all(plain)
        assert all(feed(ImuGate(descent=lambda: speed), samples)), phase
        assert feed(ImuGate(descent=lambda: 0.0), samples) == plain
    assert spiked >= 3  # the spike gate alone drops it at some phases


def test_a_touch_down_is_counted_spike_or_not_and_a_steady_descent_is_not():
    # the fusion takes a jolt for a touch-down (it re-references the barometer there): at
    # LAND_SPEED every phase shows one, a vibrating descent none, a hover none
    for phase in range(8):
        gate = ImuGate(descent=lambda: 0.5)
        feed(gate, _touch_down(0.5, phase))
        assert gate.jolts >= 1, phase
        hovering = ImuGate(descent=lambda: 0.0)
        feed(hovering, _touch_down(0.5, phase))
        assert hovering.jolts == 0
    descending = ImuGate(descent=lambda: 0.5)
    feed(descending, noisy(1000, seed=5))
    assert descending.jolts == 0


def test_a_sideways_spike_is_no_jolt():
    accels = noisy(100)
    accels[50] = HOVER + np.array([2 * SPIKE_FLOOR, 0.0, -SPIKE_FLOOR])
    assert feed(ImuGate(descent=lambda: 1.0), accels)[50] is False


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

