"""The soak's pieces that do not need an hour (sim/faults/soak.py): the flight flown back and
forth without a jump, what its summary reads from the RSS samples, the warnings it counts."""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from sim.datasets.layout import SensorSamples
from sim.faults.soak import SoakResult, _Warnings, back_and_forth
from sim.sequence import ImuSamples, Sequence
from sim.trajectory import Trajectory


def flight() -> Sequence:
    """2 s along x at 3 m/s, frames at 10 Hz, IMU at 100 Hz turning at 0.1 rad/s."""
    t = np.arange(0.0, 2.01, 0.1)
    positions = np.stack([3.0 * t, np.zeros_like(t), np.full_like(t, -12.0)], axis=1)
    quaternions = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    t_imu = np.arange(0.0, 2.001, 0.01)
    imu = ImuSamples(t_imu, np.tile([0.0, 0.0, -9.8], (len(t_imu), 1)),
                     np.tile([0.0, 0.0, 0.1], (len(t_imu), 1)))
    sensors = SensorSamples(t, Rotation.identity(len(t)).as_quat(), 12.0 + 0.0 * t,
                            12.0 + 0.0 * t, np.ones(len(t), bool))
    return Sequence("line", CameraModel(64, 48, 50.0, 50.0, 32.0, 24.0), t,
                    image_loader=lambda i: np.full((48, 64), i, np.uint8),
                    groundtruth=Trajectory(t, positions, quaternions), imu=imu,
                    extras={"sensors": sensors})


def test_every_other_pass_is_flown_backwards_without_a_jump():
    looped = back_and_forth(flight(), 3)
    assert np.all(np.diff(looped.timestamps) > 0) and len(looped) == 3 * 21 - 2
    x = looped.groundtruth.positions[:, 0]
    assert np.max(np.abs(np.diff(x))) <= 0.3 + 1e-9  # 3 m/s over 0.1 s: the turns do not jump
    assert x[20] == 6.0 and x[40] == 0.0 and x[-1] == 6.0
    shown = [int(looped.image_loader(i)[0, 0]) for i in (0, 20, 21, 40, 41)]
    assert shown == [0, 20, 19, 0, 1]
    gyro = looped.imu.gyro[:, 2]
    assert np.all(gyro[:201] > 0) and np.all(gyro[201:401] < 0) and np.all(gyro[401:] > 0)


def test_summary_figures_from_the_samples():
    samples = [(0.5, 400.0), (9.9, 480.0), (10.2, 450.0), (30.0, 500.0), (59.0, 470.0)]
    result = SoakResult(samples, 0, 0, 0, 0, [])
    assert result.rss_at(10.0) == 480.0  # the nearest sample
    assert result.peak(0.0, 10.0) == 480.0 and result.peak(50.0, 60.0) == 470.0
    assert result.per_minute() == [(0, 400.0), (9, 480.0), (10, 450.0), (30, 500.0),
                                   (59, 470.0)]


def test_warnings_and_errors_are_counted_by_logger():
    counter = _Warnings()
    log = logging.getLogger("sdvl.test-soak")
    log.addHandler(counter)
    try:
        log.info("not counted")
        log.warning("one")
        log.error("two")
    finally:
        log.removeHandler(counter)
    assert counter.counts == {"sdvl.test-soak": 2}
