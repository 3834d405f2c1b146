"""The synthetic IMU is consistent with the ground truth: integrating the noise-free samples
reproduces the trajectory; the noisy ones differ by the documented noise and biases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim.synth.flight import synthetic_sequence
from sim.synth.sensors import IMU_RATE, SensorNoise
from sim.synth.trajectory_gen import G_NED


def _derivative(R, v, omega, f):
    """d/dt of (R_w_b, velocity, position) for body rate omega and specific force f."""
    return R @ np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]],
                         [-omega[1], omega[0], 0]]), R @ f + G_NED, v


def integrate(imu, R, v, p, steps: int):
    """RK4 with step 2/rate: samples k, k+1, k+2 are the start, middle and end of a step."""
    h = 2.0 / IMU_RATE
    for k in range(0, 2 * steps, 2):
        w, a = imu.gyro[k:k + 3], imu.accel[k:k + 3]
        k1 = _derivative(R, v, w[0], a[0])
        k2 = _derivative(R + h / 2 * k1[0], v + h / 2 * k1[1], w[1], a[1])
        k3 = _derivative(R + h / 2 * k2[0], v + h / 2 * k2[1], w[1], a[1])
        k4 = _derivative(R + h * k3[0], v + h * k3[1], w[2], a[2])
        R = R + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v, p = (v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]),
                p + h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2]))
        R = Rotation.from_matrix(R).as_matrix()  # re-orthonormalise
    return R, v, p


@pytest.mark.parametrize("preset", ["hover-down", "survey-down", "room-handheld"])
def test_noise_free_imu_integrates_to_the_trajectory(preset):
    seq = synthetic_sequence(preset, frames=340, size=(64, 48), textures="procedural")
    path, imu = seq.extras["path"], seq.extras["imu_clean"]
    start = 200  # 1 s in: already moving
    sub = type(imu)(imu.t[start:], imu.accel[start:], imu.gyro[start:])
    t0 = sub.t[0]
    R, v, p = path.rotation(t0)[0], path.velocity(t0)[0], path.position(t0)
    steps = 1000  # 10 s
    R, v, p = integrate(sub, R, v, p, steps)
    t1 = sub.t[2 * steps]
    assert t1 - t0 == pytest.approx(10.0)
    assert np.linalg.norm(p - path.position(t1)) < 0.01
    angle = Rotation.from_matrix(R.T @ path.rotation(t1)[0]).magnitude()
    assert angle < 1e-4
    # the camera ground truth is the body path through the mounting
    T_w_c = seq.groundtruth.matrices()[0]
    np.testing.assert_allclose(T_w_c, path.poses(0.0)[0] @ seq.extras["T_b_c"], atol=1e-9)


def test_imu_at_rest_reads_minus_gravity_in_body_down():
    seq = synthetic_sequence("survey-down", frames=2, size=(64, 48), textures="procedural")
    clean = seq.extras["imu_clean"]
    np.testing.assert_allclose(clean.accel[0], [0, 0, -9.80665], atol=1e-6)
    np.testing.assert_allclose(clean.gyro[0], 0, atol=1e-3)


def test_noisy_imu_is_clean_plus_biases_plus_white_noise():
    seq = synthetic_sequence("hover-down", frames=300, size=(64, 48), textures="procedural")
    clean, (ba, bg) = seq.extras["imu_clean"], seq.extras["imu_bias"]
    noise = SensorNoise()
    ea = seq.imu.accel - clean.accel - ba
    eg = seq.imu.gyro - clean.gyro - bg
    assert np.std(ea) == pytest.approx(noise.accel_noise * np.sqrt(IMU_RATE), rel=0.1)
    assert np.std(eg) == pytest.approx(noise.gyro_noise * np.sqrt(IMU_RATE), rel=0.1)
    assert 0 < np.abs(ba).max() < 0.3 and 0 < np.abs(bg).max() < 0.02
