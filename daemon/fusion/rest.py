"""Whether the vehicle stands still, so the filter may fuse zero velocity (a ZUPT).

On the ground, before the map exists, nothing but the IMU says where the vehicle is; integrated
alone it drifts. The autopilot knows when a multirotor is on the ground: its land detector
(EXTENDED_SYS_STATE.landed_state, ON_GROUND while disarmed and until take-off, ArduCopter's
`ap.land_complete`, PX4's vehicle_land_detected). Without that message, a disarmed vehicle whose
IMU has been quiet (specific force steady at g, rates near zero) stands still too; a disarmed
one that is carried is not quiet. An armed vehicle is never taken to be still by its IMU alone:
a smooth hover can look as quiet as the ground. Nor is one its land detector says is on the
ground: spinning up, it may lift before the detector clears (ArduCopter's at full throttle or
half its climb acceleration); it is only held sideways then (`on_gear`).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from daemon.fusion.config import FusionConfig

GRAVITY = 9.80665
MIN_SAMPLES = 5  # IMU samples in the window before it can be called quiet
ONSET_S = 0.1  # a take-off shows in the IMU's mean over this long before the land detector
ONSET_ACCEL = 0.1  # m/s^2: a thrust change that large is no ground vibration
CONFIRM = 2  # reports in a row before a vehicle that may move is taken to be on the ground


class _Reported:
    """One flight-state flag as reported: a report that the vehicle may move counts at once,
    one that it stands still only when CONFIRM reports in a row say so (or it is the first
    word), so a corrupt message cannot stop a flying vehicle in the filter."""

    def __init__(self, still_when: bool):
        self.still_when = still_when
        self.value: tuple[float, bool] | None = None  # (time, flag)
        self._agreeing = 0

    def report(self, t: float, flag: bool) -> None:
        self._agreeing = self._agreeing + 1 if flag == self.still_when else 0
        if (flag != self.still_when or self.value is None or self.value[1] == flag
                or self._agreeing >= CONFIRM):
            self.value = (t, flag)


class _Recent:
    """Samples (time, row of floats) of the last seconds, with the rows between two times as
    one array."""

    def __init__(self, width: int):
        self.times: deque[float] = deque()
        self.rows: deque[np.ndarray] = deque()
        self.width = width

    def add(self, t: float, row: np.ndarray, keep_s: float) -> None:
        self.times.append(t)
        self.rows.append(row)
        while self.times and self.times[0] < t - keep_s:
            self.times.popleft()
            self.rows.popleft()

    def between(self, start: float, end: float, closed: bool = True) -> np.ndarray:
        """The rows stamped in [start, end] ([start, end) unless `closed`), shape (n, width)."""
        if not self.times:
            return np.empty((0, self.width))
        times = np.asarray(self.times)
        inside = (times >= start) & ((times <= end) if closed else (times < end))
        return np.asarray(self.rows)[inside]


class RestDetector:
    """Keeps the autopilot's flight state and the recent IMU and gyro samples (our clock)."""

    def __init__(self, cfg: FusionConfig):
        self.cfg = cfg
        self._landed = _Reported(still_when=True)  # on the ground
        self._armed = _Reported(still_when=False)
        self.accel = _Recent(4)  # specific force x y z and its norm
        self.rates = _Recent(1)  # |body rate|

    def on_landed(self, t: float, on_ground: bool | None) -> None:
        """The autopilot's land detector (None: it cannot tell now; the last word stands until
        it times out)."""
        if on_ground is not None:
            self._landed.report(t, on_ground)

    def on_armed(self, t: float, armed: bool) -> None:
        """HEARTBEAT's armed flag."""
        self._armed.report(t, armed)

    def on_imu(self, t: float, accel: np.ndarray) -> None:
        """A specific-force sample (body FRD, m/s^2)."""
        self.accel.add(t, np.append(accel, np.linalg.norm(accel)), 2 * self.cfg.rest_window_s)

    def on_rates(self, t: float, rates: np.ndarray) -> None:
        """Body rates (rad/s) of an ATTITUDE sample."""
        self.rates.add(t, np.array([np.linalg.norm(rates)]), 2 * self.cfg.rest_window_s)

    def _fresh(self, state: tuple[float, bool] | None, t: float) -> bool | None:
        if state is None or abs(t - state[0]) > self.cfg.flight_state_timeout_s:
            return None
        return state[1]

    def state(self, t: float) -> bool | None:
        """True when the vehicle stands still at time t, False when it may move, None when
        that cannot be told yet (no flight state, or too few IMU samples while disarmed)."""
        landed = self._fresh(self._landed.value, t)
        if landed is not None:
            if landed and self._fresh(self._armed.value, t):
                return False  # armed on its gear it may lift any moment: held sideways only
            return landed and not self.accelerating(t)
        armed = self._fresh(self._armed.value, t)
        if armed is None:
            return None
        if armed:
            return False
        window = self.accel.between(t - self.cfg.rest_window_s, t)
        return self.quiet(t) if len(window) >= MIN_SAMPLES else None

    def at_rest(self, t: float) -> bool:
        """True when the vehicle stands still at time t."""
        return self.state(t) is True

    def on_gear(self, t: float) -> bool:
        """The autopilot's land detector says the vehicle is on the ground at time t, whatever
        its IMU shows: spinning up to take off it may be lifting, but it does not slide
        sideways on its gear (the detector clears as it lifts: ArduCopter's takeoff at full
        throttle or half its climb acceleration)."""
        return self._fresh(self._landed.value, t) is True

    def accelerating(self, t: float) -> bool:
        """The IMU's mean specific force over the last ONSET_S departs from what it read just
        before (its bias included) by more than ONSET_ACCEL beyond its noise: the vehicle is
        leaving the ground, which the land detector says only later."""
        recent = self.accel.between(t - ONSET_S, t)[:, 3]
        before = self.accel.between(t - 2 * self.cfg.rest_window_s, t - ONSET_S, False)[:, 3]
        if len(recent) < 2:
            return False
        baseline = float(np.median(before)) if len(before) >= MIN_SAMPLES else GRAVITY
        spread = float(np.std(before if len(before) >= MIN_SAMPLES else recent))
        noise = 3.0 * spread / np.sqrt(len(recent))
        return abs(float(np.mean(recent)) - baseline) > ONSET_ACCEL + noise

    def quiet(self, t: float) -> bool:
        """The IMU (and gyro, when known) showed no motion over the window ending at t."""
        cfg = self.cfg
        start = t - cfg.rest_window_s
        window = self.accel.between(start, t)
        if len(window) < MIN_SAMPLES:
            return False
        steady = (np.max(np.abs(window[:, 3] - GRAVITY)) <= cfg.rest_accel_tol
                  and float(np.max(np.std(window[:, :3], axis=0))) <= cfg.rest_accel_tol / 3)
        rates = self.rates.between(start, t)
        return steady and (not len(rates) or float(rates.max()) <= cfg.rest_gyro_tol)
