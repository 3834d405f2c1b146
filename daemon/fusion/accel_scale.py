"""The map's scale from the IMU: a linear least-squares fit of the map's displacement against the
accelerometer's, over short windows of one map segment (the linear alignment that visual-inertial
systems start from).

The EKF linearises around its current scale. Starting from the wide prior (no rangefinder, say
7x off), its first fixes land far off and its covariance shrinks before the estimate gets there,
a biased scale it is sure of. Within a window
starting at time 0, the vehicle's displacement is v0 t + P(t), with P the double integral of the
IMU's acceleration in N less its bias b, and s times the map's displacement m(t) (tracker units,
in N) is the same displacement: P(t) = s m(t) + b t^2 / 2 - v0 t + c, with c the map's error at
the window's first frame. c and v0 differ per window and are eliminated in closed form; what is
left is linear in s and b, so no linearisation point is needed, and motion at constant velocity
tells nothing, as it should. The raw accelerometer is used, not the filter's bias estimate: a
filter whose scale has run off explains the mismatch with a bias, and the fit would agree with
it. The IMU is regressed on the map, not the other way round: in flight the IMU's double
integral carries decimetres of vibration and attitude error over a window, the map millimetres,
and the error in a regressor shrinks the slope (regressed on the IMU, a hover's map gave scales
5x too large, and the first tenth of a second of a leg after it 5x too small, each at a
claimed 20 %); what is left of the map's own noise is taken off as its expected share.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WINDOW_S = 2.0  # each window has its own offset and v0: short ones follow the map's drift
# the map's motion must be at least this many times what its own noise alone would give (that
# expected share of the fit's sums is taken off: noise in the regressor shrinks the slope)
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
    ms: list[np.ndarray] = field(default_factory=list)  # the map's displacement, per frame
    map_vars: list[float] = field(default_factory=list)  # its noise's variance, units^2

    def copy(self) -> _Window:
        return _Window(self.basis.copy(), self.data.copy(), self.cross.copy(), self.frames,
                       list(self.taus), list(self.weights), list(self.ms), list(self.map_vars))

    def add(self, t: float, m: np.ndarray, p: np.ndarray, weight: float,
            map_var: float) -> None:
        self.taus.append(t)
        self.map_vars.append(map_var)
        self.weights.append(weight)
        self.ms.append(np.array(m, float))
        b = np.array([1.0, t])
        y = np.stack([p, np.full(3, t * t), m], axis=1)  # (axis, y)
        self.basis += weight * np.outer(b, b)
        self.data += weight * b[None, :, None] * y[:, None, :]
        self.cross += weight * y[:, :, None] * y[:, None, :]
        self.frames += 1

    def _usable(self) -> bool:
        return self.frames >= 4 and np.linalg.det(self.basis) > 1e-12 * self.basis[0, 0] ** 2

    def normal(self) -> np.ndarray:
        """Per axis, sum y'Wy with the offset and v0 eliminated (zeros while the window has
        fewer than four frames)."""
        if not self._usable():
            return np.zeros((3, 3, 3))  # too few frames, or all at one time
        return self.cross - np.einsum("aki,kl,alj->aij", self.data, np.linalg.inv(self.basis),
                                      self.data)

    def noise(self, density: float) -> np.ndarray:
        """With the offset and v0 eliminated (M: the weights with the window's basis projected
        out): the share of sum w m^2 over the three axes that the map's white noise gives,
        3 sum_i M_ii var_i; that share per unit^2 of a noise floor at every frame, 3 sum_i M_ii;
        and the variance that white IMU noise of `density`
        gives sum w m P, sum_axes m' M C M m (C: the covariance of doubly integrated white noise
        at the frames' times, s^2 (3 t - s) / 6 for s <= t; correlated from frame to frame, so
        the residuals do not show it)."""
        if not self._usable():
            return np.zeros(3)
        tau, w = np.array(self.taus), np.array(self.weights)
        s, t = np.minimum.outer(tau, tau), np.maximum.outer(tau, tau)
        C = density**2 * s * s * (3.0 * t - s) / 6.0
        B = np.stack([np.ones_like(tau), tau], axis=1)
        WB = w[:, None] * B
        M = np.diag(w) - WB @ np.linalg.solve(B.T @ WB, WB.T)
        Mm = M @ np.array(self.ms)  # (frames, axis)
        return np.array([3.0 * float(np.diag(M) @ np.array(self.map_vars)),
                         3.0 * float(np.sum(np.diag(M))), float(np.sum(Mm * (C @ Mm)))])


@dataclass
class AccelScale:
    """The IMU's double integral and the map's position since the current window started."""

    accel_noise: float  # m/s^2/sqrt(Hz): the IMU's displacement error grows as t^1.5 / sqrt(3)
    position_std_m: float  # the tracker's least noise, metres (in units at the fit's own scale)
    start_t: float | None = None
    start_p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))
    p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    window: _Window = field(default_factory=_Window)
    closed: np.ndarray = field(default_factory=lambda: np.zeros((3, 3, 3)))  # summed normal()s
    closed_noise: np.ndarray = field(default_factory=lambda: np.zeros(3))  # windows' noise()
    density: float = 0.0  # the IMU noise the current window is weighted by
    windows: int = 0  # closed windows in the sums (a hover's are left out)
    frames: int = 0  # frames in the sums and the running window

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
                  accel_noise: float | None = None, time_offset: float = 0.0,
                  map_var: float = 0.0) -> None:
        """The map's camera position (tracker units) at time t, the map's current rotation
        into N, the IMU stream's noise density measured now (imu_noise.py; at least
        `self.accel_noise`): in flight, motor vibration makes it several times the bench
        figure, and a fit weighted by the bench figure took a hover's few centimetres for a
        scale 2-3x off at a claimed 5-10 %), and how far the IMU's stamps are behind the
        camera's (the filter's TIME_OFFSET): the camera at t saw the vehicle where the IMU
        says it is `time_offset` later. Unpaired, the first 0.1 s of a 2 m leg gave a scale
        5x too small (the map moved before the IMU's stamps said so). `map_var`: the variance
        of the map's position noise (units^2, per axis; the tracker's covariance), on top of
        `position_std_m`, which the fit converts at its own scale: converted at the filter's,
        the floor was 271 units^2 at lift-off (a runaway scale of 0.0003 m/unit) and that one
        frame's share kept the fit silent for the whole flight (closed loop, no rangefinder)."""
        if self.start_t is not None and t - self.start_t > WINDOW_S:
            self._close_window()
            self.start_t = None
        if self.start_t is None:
            self.start_t, self.start_p = t, np.asarray(p_w, float).copy()
            self.v, self.p, self.window = np.zeros(3), np.zeros(3), _Window()
        tau = t - self.start_t
        self.density = (self.accel_noise if accel_noise is None
                        else max(accel_noise, self.accel_noise))
        sigma2 = self.density**2 * tau**3 / 3 + self.position_std_m**2
        self.window.add(tau, R_n_w @ (np.asarray(p_w, float) - self.start_p),
                        self.p + time_offset * self.v, 1.0 / sigma2, map_var)
        self.frames += 1

    def _close_window(self) -> None:
        """Add the running window to the sums, unless the map's motion in it is less than
        MIN_SIGNAL_TO_NOISE times its own noise share (at the scale the sums give with it):
        such a window (a hover) adds a share known only to its size and no information. Summed,
        a 30 s hover's windows took the share from 6 % to 30 % of what was left and moved the
        fit from 0.150 to 0.186 m/unit for a 0.135 map (closed loop, no rangefinder, seed 5)."""
        normal, noise = self.window.normal(), self.window.noise(self.density)
        sums, noises = self.closed + normal, self.closed_noise + noise
        solved = self._solve(sums, noises)
        share = noise[0] if solved is None else self._share(noise, solved[0])
        if float(normal[:, 2, 2].sum()) > MIN_SIGNAL_TO_NOISE * share:
            self.closed, self.closed_noise = sums, noises
            self.windows += 1
        else:
            self.frames -= self.window.frames

    def _solve(self, sums: np.ndarray, noise: np.ndarray) -> tuple[float, float, float] | None:
        """(m/unit, the map noise's share, the map's motion) from the sums (axis, y, y), y = (P,
        t^2, m), with the bias eliminated; None without positive motion left apart from a
        bias."""
        shape = sums[:, 1, 1]  # the bias's t^2, per axis
        if not (np.all(shape > 0) and sums[:, 2, 2].sum() > 0):
            return None
        signal = float(sums[:, 2, 2].sum() - np.sum(sums[:, 2, 1] ** 2 / shape))
        product = float(sums[:, 2, 0].sum() - np.sum(sums[:, 2, 1] * sums[:, 1, 0] / shape))
        m_per_unit = self._scale(signal - noise[0], product, noise[1] * self.position_std_m**2)
        if m_per_unit is None:
            return None
        return m_per_unit, self._share(noise, m_per_unit), signal

    def _share(self, noise: np.ndarray, m_per_unit: float) -> float:
        """The map noise's share of the sums (units^2): the tracker's covariance plus the
        position_std_m floor converted at the scale m_per_unit."""
        return float(noise[0] + noise[1] * (self.position_std_m / m_per_unit) ** 2)

    def fit(self) -> tuple[float, float] | None:
        """(ln(scale), its std), or None while the map's motion so far does not give a positive
        scale apart from a bias, or is mostly the map's own noise (a hover). The IMU's
        displacement is regressed on the map's: the IMU's errors (vibration, a drifting
        attitude tilting gravity in) are far larger than the map's but only widen the fit; the
        map's noise's expected share of its sum of squares is taken off (corrected least
        squares). The std is the modelled noise's, or the residuals' where they are larger,
        plus the share's own uncertainty: the tracker's covariance is a model of the map's noise,
        too large for a camera at rest (the same pose frame after frame) and about right in a
        hover, so what taking it off changes is known only to its size. Without that, 4 s on
        the ground then a climb gave 2.39 m/unit at 1.5 % for a map of 1.61 (real-time replay);
        measuring the noise from the positions instead made a leg after a hover give 1.42 at
        14 % for a 2.2 map, and the autopilot's EKF failsafed (closed loop, seed 8)."""
        sums = self.closed + self.window.normal()
        noise = self.closed_noise + self.window.noise(self.density)
        solved = self._solve(sums, noise)
        if solved is None:
            return None
        m_per_unit, map_share, signal = solved
        informative = signal - map_share  # corrected least squares
        if not informative > MIN_SIGNAL_TO_NOISE * map_share:
            return None
        dof = 3 * (self.frames - 2 * (self.windows + 1)) - 4  # 3 axes; offset, v0 per window
        shape = sums[:, 1, 1]
        bias = (sums[:, 1, 0] - m_per_unit * sums[:, 2, 1]) / shape  # b/2 per axis
        residual = float(sums[:, 0, 0].sum() - m_per_unit * sums[:, 2, 0].sum()
                         - bias @ sums[:, 1, 0])  # the weights are per m^2
        ratio = max(residual, 0.0) / dof if dof > 0 else 1.0
        var = (max(ratio, 1.0) + noise[2] / informative) / informative  # (m/unit)^2
        # the share is a model's, known only to its size: up to share / informative of the slope
        var += (m_per_unit * map_share / informative) ** 2
        return float(np.log(m_per_unit)), float(np.sqrt(var) / m_per_unit)

    @staticmethod
    def _scale(signal: float, product: float, floor_m2: float) -> float | None:
        """The slope s (m/unit) with product = s (signal - floor_m2 / s^2): the map's noise
        floor, in metres, is floor_m2 / s^2 units^2 at the scale being fitted; the positive
        root of signal s^2 - product s - floor_m2 = 0 (None: no positive motion left)."""
        if not (signal > 0 and product > 0):
            return None
        return (product + np.sqrt(product**2 + 4.0 * signal * floor_m2)) / (2.0 * signal)
