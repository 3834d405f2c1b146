"""The small kernels the tracking path calls in its hot loops, against slow, obvious
references: rigid transforms entry by entry, the 2x2 inverse, the Cholesky solve of normal
equations, the found/missed counts of a tracked frame, RANSAC's subsets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from vo.map_matching import _count_found_missed
from vo.matcher import inverse2
from vo.normal_equations import solve_spd
from vo.outlier_rejection import SUBSET, random_subsets
from vo.se3 import (
    adjoint,
    compose,
    exp_se3,
    exp_so3,
    inv_se3,
    orthonormalized,
    rotvec,
    scaled_motion,
    skew,
)


def _twist_matrix(xi: np.ndarray) -> np.ndarray:
    M = np.zeros((4, 4))
    M[:3, :3] = skew(np.ascontiguousarray(xi[3:]))
    M[:3, 3] = xi[:3]
    return M


@pytest.mark.parametrize("size", [1e-10, 1e-3, 0.5, 2.0])
def test_rigid_transforms_against_matrix_algebra(size):
    rng = np.random.default_rng(0)
    for _ in range(20):
        xi, eta = rng.normal(size=6) * size, rng.normal(size=6)
        T, U = exp_se3(xi), exp_se3(eta)
        assert np.allclose(T, expm(_twist_matrix(xi)), atol=1e-12)
        assert np.allclose(inv_se3(T), np.linalg.inv(T), atol=1e-12)
        assert np.allclose(compose(T, U), T @ U, atol=1e-12)
        assert np.allclose(adjoint(T) @ eta, _vee(T @ _twist_matrix(eta) @ np.linalg.inv(T)))


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-3, 0.5, 2.0, 3.0, np.pi - 1e-6])
def test_rotations_against_scipy(angle):
    """exp_so3 and rotvec against scipy's Rotation, small angles to near pi; rotvec also
    through the four branches of its quaternion (each diagonal entry the largest)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        axis = rng.normal(size=3)
        w = angle * axis / np.linalg.norm(axis)
        R = Rotation.from_rotvec(w).as_matrix()
        assert np.allclose(exp_so3(w), R, rtol=0, atol=1e-15)
        assert np.allclose(rotvec(R), Rotation.from_matrix(R).as_rotvec(), rtol=1e-9,
                           atol=1e-15)
        assert np.allclose(exp_so3(rotvec(R)), R, rtol=0, atol=1e-15)


@pytest.mark.parametrize("size", [1e-10, 1e-3, 0.3, 1.5])
def test_scaled_motion_is_the_motion_repeated_or_split(size):
    """scaled_motion(T, k) = T^k for whole k, its half taken twice is T, and none of it is no
    motion (T from scipy's matrix exponential)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        T = expm(_twist_matrix(rng.normal(size=6) * size))
        np.testing.assert_allclose(scaled_motion(T, 1.0), T, atol=1e-9)
        np.testing.assert_allclose(scaled_motion(T, 3.0), T @ T @ T, atol=1e-9)
        half = scaled_motion(T, 0.5)
        np.testing.assert_allclose(half @ half, T, atol=1e-9)
        np.testing.assert_allclose(scaled_motion(T, 0.0), np.eye(4), atol=1e-12)


def test_rotvec_at_pi_gives_a_rotation_that_turns_back_the_same():
    for axis in np.eye(3):
        R = Rotation.from_rotvec(np.pi * axis).as_matrix()
        assert np.allclose(np.abs(rotvec(R)), np.pi * axis, atol=1e-12)
        assert np.allclose(exp_so3(rotvec(R)), R, atol=1e-12)


def _vee(M: np.ndarray) -> np.ndarray:
    return np.array([M[0, 3], M[1, 3], M[2, 3], M[2, 1], M[0, 2], M[1, 0]])


def test_orthonormalized_is_the_nearest_rotation():
    rng = np.random.default_rng(1)
    T = exp_se3(rng.normal(size=6))
    noisy = T.copy()
    noisy[:3, :3] += rng.normal(size=(3, 3)) * 1e-6
    R = orthonormalized(noisy)[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-14) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(R, T[:3, :3], atol=1e-5)
    U, _, Vt = np.linalg.svd(noisy[:3, :3])
    assert np.allclose(R, U @ Vt, atol=1e-14)


def test_inverse2_against_numpy():
    rng = np.random.default_rng(2)
    for scale in (1e-3, 1.0, 1e3):
        for _ in range(200):
            A = rng.normal(size=(2, 2)) * scale
            assert np.allclose(inverse2(A), np.linalg.inv(A), rtol=1e-12, atol=0.0)


def test_solve_spd_against_numpy_and_refuses_an_indefinite_matrix():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(40, 6))
    H, b = J.T @ J, rng.normal(size=6)
    det, x = solve_spd(H, b)
    assert np.allclose(x, np.linalg.solve(H, b), rtol=1e-10)
    assert det == pytest.approx(np.linalg.det(H), rel=1e-10)
    indefinite = H.copy()
    indefinite[2, 2] = -1.0
    assert solve_spd(indefinite, b)[0] == 0.0
    assert solve_spd(np.full((6, 6), np.nan), b)[0] == 0.0


def test_found_missed_counts_against_set_difference():
    rng = np.random.default_rng(4)
    n_found = rng.integers(0, 5, 300)
    n_missed = rng.integers(0, 15, 300)
    attempted = np.sort(rng.choice(300, 120, replace=False))
    ids = rng.permutation(attempted)[:70]
    inlier = rng.random(70) < 0.8
    n_unmatched = rng.integers(0, 4, 300)
    found, missed_counts, streak = n_found.copy(), n_missed.copy(), n_unmatched.copy()
    hopeless = _count_found_missed(found, missed_counts, streak, ids, inlier, attempted, 10)
    ref_found, ref_missed, ref_streak = n_found.copy(), n_missed.copy(), n_unmatched.copy()
    ref_found[ids[inlier]] += 1
    missed = np.setdiff1d(attempted, ids)
    ref_missed[missed] += 1
    ref_streak[attempted] += 1
    ref_streak[ids] = 0
    keep = (ref_missed[missed] > 10) & (ref_missed[missed] > 2 * ref_found[missed])
    assert np.array_equal(found, ref_found) and np.array_equal(missed_counts, ref_missed)
    assert np.array_equal(streak, ref_streak) and (streak[missed] > 0).all()
    assert np.array_equal(hopeless, missed[keep]) and len(hopeless) > 0


@pytest.mark.parametrize("n", [6, 50, 300])
def test_random_subsets_are_the_smallest_draws(n):
    subsets = random_subsets(n, 40, 7)
    draws = np.random.default_rng(7).random((40, n))
    assert np.array_equal(subsets, np.argsort(draws, axis=1)[:, :SUBSET])
