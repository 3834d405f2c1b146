"""The attitude track keeps only attitudes a vehicle can have next to its neighbours
(daemon/fusion/attitude.py): a corrupt tilt or heading is refused, a lasting change followed."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.fusion.attitude import STRIKES, AttitudeTrack
from daemon.fusion.sensors import Attitude

STILL = np.zeros(3)


def attitude(t: float, roll: float = 0.0, yaw: float = 0.0, rates=STILL) -> Attitude:
    return Attitude(t, Rotation.from_euler("ZYX", [yaw, 0.0, roll]).as_matrix(), np.asarray(rates))


def test_a_turn_is_kept_and_a_jump_refused():
    track = AttitudeTrack(timeout_s=0.1, keep_s=5.0)
    turning = [track.add(attitude(0.02 * k, yaw=0.04 * k, rates=[0, 0, 2.0])) for k in range(50)]
    assert all(turning)  # 2 rad/s of yaw
    assert not track.add(attitude(1.0, roll=0.6, yaw=2.0))  # 34 degrees of roll in 20 ms
    assert not track.add(attitude(1.02, yaw=2.04, rates=[50.0, 0.0, 2.0]))  # absurd rates
    assert track.add(attitude(1.02, yaw=2.04, rates=[0, 0, 2.0]))
    assert track.refused == 2


def test_a_lasting_change_is_followed():
    track = AttitudeTrack(timeout_s=0.1, keep_s=5.0)
    for k in range(10):
        track.add(attitude(0.02 * k))
    kept = [track.add(attitude(0.2 + 0.02 * k, yaw=1.0)) for k in range(STRIKES + 2)]
    assert kept == [False] * (STRIKES - 1) + [True] * 3  # the AHRS reset its heading


def test_a_tilt_its_rates_do_not_explain_is_refused():
    """At 20 Hz a vehicle could turn half a radian between samples at the rate limit; the body
    rates say it does not, so a roll 5 degrees off is no turn (it would leak 0.9 m/s^2 of
    gravity into the IMU's acceleration)."""
    track = AttitudeTrack(timeout_s=0.1, keep_s=5.0)
    for k in range(10):
        assert track.add(attitude(0.05 * k, roll=0.2 * 0.05 * k, rates=[0.2, 0, 0]))
    assert not track.add(attitude(0.5, roll=0.1 + np.radians(5.0), rates=[0.2, 0, 0]))
    assert track.add(attitude(0.5, roll=0.1, rates=[0.2, 0, 0]))
    assert track.add(attitude(0.55, roll=0.13, rates=[1.0, 0, 0]))  # rolling faster: 16 rad/s^2


def test_corrupt_samples_among_good_ones_are_never_followed():
    track = AttitudeTrack(timeout_s=0.1, keep_s=5.0)
    rng = np.random.default_rng(4)
    kept = []
    for k in range(40):
        corrupt = k >= 10 and k % 4 != 0  # three of four samples, each off its own way
        roll = float(rng.uniform(0.2, 0.6)) * rng.choice([-1, 1]) if corrupt else 0.0
        kept.append(track.add(attitude(0.05 * k, roll=roll)))
    assert all(kept[k] for k in range(40) if k < 10 or k % 4 == 0)
    assert not any(kept[k] for k in range(10, 40) if k % 4 != 0)


def test_a_stream_that_keeps_being_refused_is_said_once_and_its_recovery_too():
    said: list[str] = []
    track = AttitudeTrack(timeout_s=0.1, keep_s=5.0, report=said.append)
    rng = np.random.default_rng(5)
    for k in range(80):  # 4 s at 20 Hz: three of four samples corrupt from 0.5 s on
        corrupt = k >= 10 and k % 4 != 0
        roll = float(rng.uniform(0.2, 0.6)) * rng.choice([-1, 1]) if corrupt else 0.0
        track.add(attitude(0.05 * k, roll=roll))
    assert len(said) == 1 and said[0].startswith("ATTITUDE doubted")
    for k in range(80, 80 + 20 * 11):  # 11 s clean
        assert track.add(attitude(0.05 * k))
    assert len(said) == 2 and "used again" in said[1]
