"""Smooth body trajectories in the NED world: degree-7 splines through timed waypoints.

Positions are a C6 spline with zero velocity, acceleration and jerk at both ends, so the
acceleration and the angular rate an IMU measures are smooth and start and end at rest.
Attitude is either that of a multirotor (thrust axis along the specific force, yaw from its own
spline) or free (a hand-held device: yaw, pitch and roll splines).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.spatial.transform import Rotation

GRAVITY = 9.80665
G_NED = np.array([0.0, 0.0, GRAVITY])
_REST = ([(1, 0.0), (2, 0.0), (3, 0.0)], [(1, 0.0), (2, 0.0), (3, 0.0)])
_DIFF_STEP = 1e-4  # s, central difference of the attitude for the angular rate


def rest_spline(t: np.ndarray, values: np.ndarray) -> BSpline:
    """A degree-7 spline through (t, values) that starts and ends at rest."""
    values = np.asarray(values, dtype=np.float64)
    bc = tuple([(d, np.zeros(values.shape[1:])) for d, _ in end] for end in _REST)
    return make_interp_spline(np.asarray(t, float), values, k=7, bc_type=bc)


@dataclass
class BodyPath:
    """Body (FRD) pose T_w_b over [t0, t1]: `position` spline (N, 3) NED; `yaw` spline; for
    free attitude also `pitch` and `roll` splines, else the multirotor tilt."""

    position: BSpline
    yaw: BSpline
    pitch: BSpline | None = None
    roll: BSpline | None = None

    @property
    def duration(self) -> float:
        """End time of the path (it starts at 0)."""
        return float(self.position.t[-1])

    def _clip(self, t) -> np.ndarray:
        return np.clip(np.atleast_1d(np.asarray(t, float)), 0.0, self.duration)

    def accel(self, t) -> np.ndarray:
        """World acceleration (N, 3) m/s^2."""
        return self.position(self._clip(t), 2)

    def velocity(self, t) -> np.ndarray:
        """World velocity (N, 3) m/s."""
        return self.position(self._clip(t), 1)

    def rotation(self, t) -> np.ndarray:
        """R_w_b (N, 3, 3)."""
        t = self._clip(t)
        yaw = self.yaw(t)
        if self.pitch is not None:
            angles = np.column_stack([yaw, self.pitch(t), self.roll(t)])
            return Rotation.from_euler("ZYX", angles).as_matrix()
        down = -(self.accel(t) - G_NED)
        down /= np.linalg.norm(down, axis=1, keepdims=True)
        heading = np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)])
        right = np.cross(down, heading)
        right /= np.linalg.norm(right, axis=1, keepdims=True)
        forward = np.cross(right, down)
        return np.stack([forward, right, down], axis=2)

    def poses(self, t) -> np.ndarray:
        """T_w_b (N, 4, 4)."""
        t = self._clip(t)
        T = np.tile(np.eye(4), (t.size, 1, 1))
        T[:, :3, :3] = self.rotation(t)
        T[:, :3, 3] = self.position(t)
        return T

    def gyro(self, t) -> np.ndarray:
        """Body angular rate (N, 3) rad/s: vee(R^T dR/dt) by central difference."""
        t = np.atleast_1d(np.asarray(t, float))
        R0, R1 = self.rotation(t - _DIFF_STEP), self.rotation(t + _DIFF_STEP)
        R = self.rotation(t)
        W = np.einsum("nji,njk->nik", R, (R1 - R0) / (2 * _DIFF_STEP))
        return np.column_stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0],
                                W[:, 1, 0] - W[:, 0, 1]]) / 2

    def specific_force(self, t) -> np.ndarray:
        """What an ideal accelerometer at the body origin reads (N, 3): R_b_w (a - g)."""
        f_w = self.accel(t) - G_NED
        return np.einsum("nji,nj->ni", self.rotation(t), f_w)


def path_from_waypoints(t, positions, yaw, pitch=None, roll=None) -> BodyPath:
    """A BodyPath through timed waypoints (angles in radians, unwrapped by the caller)."""
    t = np.asarray(t, float)
    if pitch is None:
        return BodyPath(rest_spline(t, positions), rest_spline(t, yaw))
    roll = np.zeros_like(t) if roll is None else roll
    return BodyPath(rest_spline(t, positions), rest_spline(t, yaw), rest_spline(t, pitch),
                    rest_spline(t, roll))


def ramp_speed_profile(length: float, speed: float, ramp_s: float, dt: float) -> np.ndarray:
    """Times every `dt` and the distance covered along a path of `length` m at `speed`, with
    smooth speed-up and slow-down over `ramp_s` seconds: (M, 2) rows (t, s)."""
    cruise = max(length / speed - ramp_s, 0.0)
    total = cruise + 2 * ramp_s
    t = np.arange(0.0, total + dt / 2, dt)
    ramp = lambda x: np.clip(x, 0, 1) ** 2 * (3 - 2 * np.clip(x, 0, 1))  # noqa: E731
    v = speed * np.minimum(ramp(t / ramp_s), ramp((total - t) / ramp_s))
    s = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * dt)])
    return np.column_stack([t, s * length / max(s[-1], 1e-9)])


def rounded_polyline(corners: np.ndarray, radius: float, step: float = 0.25) -> np.ndarray:
    """Points every ~`step` m along a polyline whose corners are rounded with `radius` m."""
    corners = np.asarray(corners, float)
    pts = [corners[0]]
    for i in range(1, len(corners) - 1):
        a, b, c = corners[i - 1], corners[i], corners[i + 1]
        d0, d1 = (b - a) / np.linalg.norm(b - a), (c - b) / np.linalg.norm(c - b)
        r = min(radius, np.linalg.norm(b - a) / 2, np.linalg.norm(c - b) / 2)
        p0, p1 = b - d0 * r, b + d1 * r
        pts += list(_segment(pts[-1], p0, step)[1:])
        s = np.linspace(0, 1, 9)[1:, None]
        pts += list((1 - s) ** 2 * p0 + 2 * s * (1 - s) * b + s**2 * p1)  # quadratic Bezier
    pts += list(_segment(pts[-1], corners[-1], step)[1:])
    return np.array(pts)


def _segment(a, b, step):
    n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
    return a + np.linspace(0, 1, n + 1)[:, None] * (b - a)


def travel(points: np.ndarray, speed: float, ramp_s: float = 2.0,
           dt: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Waypoint times and positions for flying along `points` at `speed` from rest to rest."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    profile = ramp_speed_profile(arc[-1], speed, ramp_s, dt)
    pos = np.column_stack([np.interp(profile[:, 1], arc, points[:, k]) for k in range(3)])
    return profile[:, 0], pos
