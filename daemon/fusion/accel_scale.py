"""The map's scale from the IMU: a linear least-squares fit of the map's displacement against the
accelerometer's, over short windows of one map segment (the linear alignment that visual-inertial
systems start from).

The EKF linearises around its current scale. Starting from the wide prior (no rangefinder, say
7x off), its first fixes land far off and its covariance shrinks before the estimate gets there,
a biased scale it is sure of. Within a window
starting at time 0, the vehicle's displacement is v0 t + P(t), with P the double integral of the
IMU's acceleration in N, and the map's displacement m(t) (tracker units, in N) over the scale is
the same displacement: m(t) = (v0 t + P(t) - b t^2 / 2) / s + c, with c the map's error at the
window's first frame and b the accelerometer's bias in N. c and v0 differ per window and are
eliminated in closed form; what is left is linear in 1/s and b/s, so no linearisation point is
needed, and motion at constant velocity tells nothing, as it should. The raw accelerometer is
used, not the filter's bias estimate: a filter whose scale has run off explains the mismatch
with a bias, and the fit would agree with it. The map is regressed on the IMU, not the other
way round: the map's noise would pull a fit on it towards zero wherever the motion is nearly
uniform.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WINDOW_S = 2.0  # each window has its own offset and v0: short ones follow the map's drift
# the IMU's motion must explain at least this many times what its noise alone would (its
# expected share of the fit's sums is taken off: a regression on a noisy regressor shrinks the
# slope, here 1/scale, by signal / (signal + noise))
MIN_SIGNAL_TO_NOISE = 2.0


@dataclass
class _Window:
    """Weighted sums over the frames of one window, per N axis: of the basis (1, t) that the
    window's own offset and v0 span, and of y = (P, t^2, m): the IMU's displacement, the bias's
    shape and the map's displacement."""

    basis: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))  # sum w b b'
    data: np.ndarray = field(default_factory=lambda: np.zeros((3, 2, 3)))  # sum w b y'
    cross: np.ndarray = field(default_factory=lambda: np.zeros((3, 3, 3)))  # sum w y y'
    frames: int = 0
    taus: list[float] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)
    ps: list[np.ndarray] = field(default_factory=list)  # the IMU's displacement, per frame

    def copy(self) -> _Window:
        return _Window(self.basis.copy(), self.data.copy(), self.cross.copy(), self.frames,
                       list(self.taus), list(self.weights), list(self.ps))

    def add(self, t: float, m: np.ndarray, p: np.ndarray, weight: float) -> None:
        self.taus.append(t)
        self.weights.append(weight)
        self.ps.append(np.array(p, float))
        b = np.array([1.0, t])
        y = np.stack([p, np.full(3, t * t), m], axis=1)  # (axis, y)
        self.basis += weight * np.outer(b, b)
        self.data += weight * b[None, :, None] * y[:, None, :]
        self.cross += weight * y[:, :, None] * y[:, None, :]
        self.frames += 1

    def normal(self) -> np.ndarray:
        """Per axis, sum y'Wy with the offset and v0 eliminated (zeros while the window has
        fewer than four frames)."""
        if self.frames < 4 or not np.linalg.det(self.basis) > 1e-12 * self.basis[0, 0] ** 2:
            return np.zeros((3, 3, 3))  # too few frames, or all at one time
        return self.cross - np.einsum("aki,kl,alj->aij", self.data, np.linalg.inv(self.basis),
                                      self.data)

    def noise(self, density: float) -> tuple[float, float]:
        """What white IMU noise of `density` does to the sums once the offset and v0 are
        eliminated (M: the weights with the window's basis projected out; C: the covariance
        of doubly integrated white noise at the frames' times, s^2 (3 t - s) / 6 for s <= t):
        its expected share of sum w P^2 over the three axes, 3 trace(M C), and the variance it
        gives sum w P m per unit of 1/scale, sum_axes P' M C M P (the noise is correlated
        from frame to frame: the residuals do not show it)."""
        if self.frames < 4 or not np.linalg.det(self.basis) > 1e-12 * self.basis[0, 0] ** 2:
            return 0.0, 0.0
        tau, w = np.array(self.taus), np.array(self.weights)
        s, t = np.minimum.outer(tau, tau), np.maximum.outer(tau, tau)
        C = density**2 * s * s * (3.0 * t - s) / 6.0
        B = np.stack([np.ones_like(tau), tau], axis=1)
        WB = w[:, None] * B
        M = np.diag(w) - WB @ np.linalg.solve(B.T @ WB, WB.T)
        MP = M @ np.array(self.ps)  # (frames, axis)
        return 3.0 * float(np.sum(M * C)), float(np.sum(MP * (C @ MP)))


@dataclass
class AccelScale:
    """The IMU's double integral and the map's position since the current window started."""

    accel_noise: float  # m/s^2/sqrt(Hz): the IMU's displacement error grows as t^1.5 / sqrt(3)
    position_std_m: float  # the tracker's, metres
    start_t: float | None = None
    start_p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))
    p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    window: _Window = field(default_factory=_Window)
    closed: np.ndarray = field(default_factory=lambda: np.zeros((3, 3, 3)))  # summed normal()s
    closed_noise: np.ndarray = field(default_factory=lambda: np.zeros(2))  # windows' noise()
    density: float = 0.0  # the IMU noise the current window is weighted by
    windows: int = 0
    frames: int = 0

    def copy(self) -> AccelScale:
        """An independent copy (the filter's snapshots)."""
        return AccelScale(self.accel_noise, self.position_std_m, self.start_t,
                          self.start_p.copy(), self.v.copy(), self.p.copy(), self.window.copy(),
                          self.closed.copy(), self.closed_noise.copy(), self.density,
                          self.windows,
                          self.frames)

    def integrate(self, dt: float, acceleration: np.ndarray) -> None:
        """The accelerometer's specific force in N plus gravity, held for dt seconds."""
        if self.start_t is not None:
            self.p += self.v * dt + 0.5 * acceleration * dt**2
            self.v += acceleration * dt

    def interrupt(self) -> None:
        """A gap in the IMU: the running window is dropped, the next frame starts another."""
        self.start_t = None

    def add_frame(self, t: float, p_w: np.ndarray, R_n_w: np.ndarray,
                  accel_noise: float | None = None) -> None:
        """The map's camera position (tracker units) at time t, the map's current rotation
        into N, and the IMU stream's noise density measured now (imu_noise.py; at least
        `self.accel_noise`): in flight, motor vibration makes it several times the bench
        figure, and a fit weighted by the bench figure took a hover's few centimetres for a
        scale 2-3x off at a claimed 5-10 %."""
        if self.start_t is not None and t - self.start_t > WINDOW_S:
            self.closed += self.window.normal()
            self.closed_noise += self.window.noise(self.density)
            self.windows += 1
            self.start_t = None
        if self.start_t is None:
            self.start_t, self.start_p = t, np.asarray(p_w, float).copy()
            self.v, self.p, self.window = np.zeros(3), np.zeros(3), _Window()
        tau = t - self.start_t
        self.density = (self.accel_noise if accel_noise is None
                        else max(accel_noise, self.accel_noise))
        sigma2 = self.density**2 * tau**3 / 3 + self.position_std_m**2
        self.window.add(tau, R_n_w @ (np.asarray(p_w, float) - self.start_p), self.p,
                        1.0 / sigma2)
        self.frames += 1

    def fit(self) -> tuple[float, float] | None:
        """(ln(scale), its std), or None while the motion so far does not give a positive
        scale apart from a bias, or the IMU's displacement is mostly its own noise (a hover).
        The noise's expected share of the IMU's sum of squares is taken off (corrected least
        squares for an error in the regressor). The std is the modelled noise's, or the
        residuals' where they are larger."""
        sums = self.closed + self.window.normal()  # (axis, y, y), y = (P, t^2, m)
        N = np.zeros((4, 4))  # unknowns: units per metre, and it times -b/2 per axis
        r = np.zeros(4)
        N[0, 0], r[0] = sums[:, 0, 0].sum(), sums[:, 0, 2].sum()
        noise, spread = self.closed_noise + self.window.noise(self.density)
        if not N[0, 0] > (1.0 + MIN_SIGNAL_TO_NOISE) * noise:
            return None
        N[0, 0] -= noise
        N[0, 1:] = N[1:, 0] = sums[:, 0, 1]
        N[1:, 1:] = np.diag(sums[:, 1, 1])
        r[1:] = sums[:, 1, 2]
        if not np.all(np.diag(N) > 0):
            return None
        try:
            cov = np.linalg.inv(N)
        except np.linalg.LinAlgError:
            return None
        theta = cov @ r
        units_per_m = float(theta[0])
        if not (units_per_m > 0 and np.isfinite(units_per_m) and cov[0, 0] > 0):
            return None
        dof = 3 * (self.frames - 2 * (self.windows + 1)) - 4  # 3 axes; offset, v0 per window
        # the weights are per metre^2: in map units the residuals' variance is units_per_m^2
        # times the modelled one
        residual = max(float(sums[:, 2, 2].sum() - theta @ r), 0.0)
        ratio = residual / (dof * units_per_m**2) if dof > 0 else 1.0
        return float(-np.log(units_per_m)), float(np.sqrt(max(ratio, 1.0) * cov[0, 0]
                                                          + spread / N[0, 0] ** 2))
