"""Rigid transforms as 4x4 float64 matrices; twists ordered (translation xyz, rotation xyz)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def skew(w):
    """The 3x3 cross-product matrix of w."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


@numba.njit(cache=True, nogil=True)
def exp_se3(xi):
    """The transform exp(xi) for a twist xi = (v, w)."""
    T = np.empty((4, 4))
    exp_se3_into(xi, T)
    return T


@numba.njit(cache=True, nogil=True)
def exp_se3_into(xi, T):
    """Write exp(xi) into the 4x4 array T, entry by entry: the kernels' hot loops call it, and
    neither 3x3 products through BLAS nor allocating the result pay for the arithmetic
    (RANSAC's hypothesis loop took 0.73x the time without the allocations)."""
    v0, v1, v2, w0, w1, w2 = xi[0], xi[1], xi[2], xi[3], xi[4], xi[5]
    theta = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if theta < 1e-8:
        a, b, c = 1.0, 0.5, 1.0 / 6.0
    else:
        a = np.sin(theta) / theta
        b = (1.0 - np.cos(theta)) / (theta * theta)
        c = (theta - np.sin(theta)) / (theta * theta * theta)
    # W = skew(w), W2 = W @ W = w w^T - theta^2 I
    W = ((0.0, -w2, w1), (w2, 0.0, -w0), (-w1, w0, 0.0))
    wv = (w0, w1, w2)
    vv = (v0, v1, v2)
    for i in range(3):
        t = 0.0
        for j in range(3):
            eye = 1.0 if i == j else 0.0
            W2 = wv[i] * wv[j] - (theta * theta if i == j else 0.0)
            T[i, j] = eye + a * W[i][j] + b * W2
            t += (eye + b * W[i][j] + c * W2) * vv[j]
        T[i, 3] = t
    T[3, 0] = T[3, 1] = T[3, 2] = 0.0
    T[3, 3] = 1.0


@numba.njit(cache=True, nogil=True)
def compose(A, B):
    """A @ B for rigid transforms (bottom rows 0 0 0 1)."""
    out = np.empty((4, 4))
    compose_into(A, B, out)
    return out


@numba.njit(cache=True, nogil=True)
def compose_into(A, B, out):
    """Write A @ B for rigid transforms into `out` (neither A nor B), entry by entry."""
    for i in range(3):
        for j in range(4):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
        out[i, 3] += A[i, 3]
    out[3, 0] = out[3, 1] = out[3, 2] = 0.0
    out[3, 3] = 1.0


def left_jacobian(xi: np.ndarray) -> np.ndarray:
    """6x6 left Jacobian of exp_se3 at the twist xi = (v, w): exp(xi + d) = exp(J d) exp(xi)
    to first order in d (Barfoot & Furgale 2014, eq. 102), so a solver that adds d to xi
    moves the transform by the left perturbation J d."""
    v, w = xi[:3], xi[3:]
    theta2 = float(w @ w)
    theta = np.sqrt(theta2)
    W, V = skew(w), skew(np.ascontiguousarray(v))
    if theta < 1e-2:  # series: the closed forms cancel catastrophically near 0
        a, b = 0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0
        c, d = 1.0 / 24.0 - theta2 / 720.0, 1.0 / 120.0 - theta2 / 2520.0
    else:
        s, co = np.sin(theta), np.cos(theta)
        a, b = (1.0 - co) / theta2, (theta - s) / (theta2 * theta)
        c = (theta2 + 2.0 * co - 2.0) / (2.0 * theta2 * theta2)
        d = (2.0 * theta - 3.0 * s + theta * co) / (2.0 * theta2 * theta2 * theta)
    W2 = W @ W
    WVW = W @ V @ W
    Q = (0.5 * V + b * (W @ V + V @ W + WVW) + c * (W2 @ V + V @ W2 - 3.0 * WVW)
         + d * (WVW @ W + W @ WVW))
    J = np.zeros((6, 6))
    J[:3, :3] = J[3:, 3:] = np.eye(3) + a * W + b * W2
    J[:3, 3:] = Q
    return J


def scaled_motion(T: np.ndarray, ratio: float) -> np.ndarray:
    """exp(ratio log T): the rigid motion T carried on at the same screw velocity for `ratio`
    times its duration (2: twice as far about the same axis; 0.5: half way)."""
    w = rotvec(np.ascontiguousarray(T[:3, :3]))
    V = left_jacobian(np.concatenate([np.zeros(3), w]))[:3, :3]  # exp_se3's t = V v
    return exp_se3(ratio * np.concatenate([np.linalg.solve(V, T[:3, 3]), w]))


@numba.njit(cache=True, nogil=True)
def inv_se3(T):
    """The inverse of a rigid transform."""
    out = np.eye(4)
    for i in range(3):
        for j in range(3):
            out[i, j] = T[j, i]
        out[i, 3] = -(T[0, i] * T[0, 3] + T[1, i] * T[1, 3] + T[2, i] * T[2, 3])
    return out


@numba.njit(cache=True, nogil=True)
def transform(T, X, Y, Z):
    """T applied to one point."""
    return (T[0, 0] * X + T[0, 1] * Y + T[0, 2] * Z + T[0, 3],
            T[1, 0] * X + T[1, 1] * Y + T[1, 2] * Z + T[1, 3],
            T[2, 0] * X + T[2, 1] * Y + T[2, 2] * Z + T[2, 3])


@numba.njit(cache=True, nogil=True)
def plane_jacobian(X, Y, Z, J):
    """Fill J (2x6) with d(X/Z, Y/Z)/d(xi) for the left perturbation exp(xi) * T of the point."""
    iz = 1.0 / Z
    x = X * iz
    y = Y * iz
    J[0, 0] = iz
    J[0, 1] = 0.0
    J[0, 2] = -x * iz
    J[0, 3] = -x * y
    J[0, 4] = 1.0 + x * x
    J[0, 5] = -y
    J[1, 0] = 0.0
    J[1, 1] = iz
    J[1, 2] = -y * iz
    J[1, 3] = -(1.0 + y * y)
    J[1, 4] = x * y
    J[1, 5] = x


@numba.njit(cache=True, nogil=True)
def adjoint(T):
    """6x6 adjoint of T for twists (v, w): exp(Ad xi) T = T exp(xi)."""
    R = np.ascontiguousarray(T[:3, :3])
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[:3, 3:] = skew(np.ascontiguousarray(T[:3, 3])) @ R
    out[3:, 3:] = R
    return out


@numba.njit(cache=True, nogil=True)
def log_so3(R):
    """The rotation vector w with exp(skew(w)) = R (angle below pi)."""
    c = min(max((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    theta = np.arccos(c)
    k = 0.5 if theta < 1e-8 else 0.5 * theta / np.sin(theta)
    return np.array([k * (R[2, 1] - R[1, 2]), k * (R[0, 2] - R[2, 0]), k * (R[1, 0] - R[0, 1])])


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix in degrees."""
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


@numba.njit(cache=True, nogil=True)
def orthonormalized(T):
    """T with its rotation block projected back onto SO(3) (removes round-off drift)."""
    U, _, Vt = np.linalg.svd(np.ascontiguousarray(T[:3, :3]))
    D = np.eye(3)
    D[2, 2] = np.linalg.det(U @ Vt)
    out = T.copy()
    out[:3, :3] = U @ D @ Vt
    return out


@numba.njit(cache=True, nogil=True)
def exp_so3(w):
    """exp(skew(w)): the rotation matrix of a rotation vector (Rodrigues' formula). The fusion
    turns its attitude with one per IMU sample, where scipy's Rotation took 35 us a call."""
    theta = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if theta < 1e-8:
        a, b = 1.0, 0.5
    else:
        a = np.sin(theta) / theta
        b = 2.0 * (np.sin(0.5 * theta) / theta) ** 2  # (1 - cos) / theta^2 without cancelling
    R = np.empty((3, 3))
    W = ((0.0, -w[2], w[1]), (w[2], 0.0, -w[0]), (-w[1], w[0], 0.0))
    for i in range(3):
        for j in range(3):
            W2 = w[i] * w[j] - (theta * theta if i == j else 0.0)  # skew(w) @ skew(w)
            R[i, j] = (1.0 if i == j else 0.0) + a * W[i][j] + b * W2
    return R


@numba.njit(cache=True, nogil=True)
def rotvec(R):
    """The rotation vector of a rotation matrix, any angle up to pi (log_so3 is for the
    smaller ones): through its unit quaternion, from the largest of its four squared
    components (Shepperd's method), so neither a small angle nor one near pi loses digits."""
    r00, r11, r22 = R[0, 0], R[1, 1], R[2, 2]
    trace = r00 + r11 + r22
    if trace >= r00 and trace >= r11 and trace >= r22:
        s = 2.0 * np.sqrt(1.0 + trace)
        qw, qx, qy, qz = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (
            R[1, 0] - R[0, 1]) / s
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * np.sqrt(1.0 + r00 - r11 - r22)
        qw, qx, qy, qz = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (
            R[0, 2] + R[2, 0]) / s
    elif r11 >= r22:
        s = 2.0 * np.sqrt(1.0 + r11 - r00 - r22)
        qw, qx, qy, qz = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (
            R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + r22 - r00 - r11)
        qw, qx, qy, qz = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (
            R[1, 2] + R[2, 1]) / s, 0.25 * s
    if qw < 0.0:
        qw, qx, qy, qz = -qw, -qx, -qy, -qz
    n = np.sqrt(qx * qx + qy * qy + qz * qz)
    # 2 atan(n / qw) / n, by its series where n / qw is tiny
    k = 2.0 / qw * (1.0 - (n / qw) ** 2 / 3.0) if n < 1e-6 * qw else 2.0 * np.arctan2(n, qw) / n
    return np.array([k * qx, k * qy, k * qz])
