"""The autopilot's attitude over the last seconds, at any time in between or a little after.

A corrupt or forged ATTITUDE arrives with a valid CRC, and the filter turns the IMU's specific
force with it: a wrong tilt leaks gravity into the acceleration. A sample is checked against its
nearest kept neighbour in time, turned by the body rates both report: its tilt (the direction of
gravity in the body) must be within TILT_NOISE_RAD plus what an angular acceleration of
MAX_ANGULAR_ACCEL can add to the rates' prediction, its whole rotation (heading included, the
compass being noisier) within NOISE_RAD + MAX_RATE_RAD_S times the time between them, and its
rates within MAX_RATE_RAD_S. STRIKES refused samples in a row that agree with each other by the
same test are a real change (a new attitude source, a reset of the autopilot's AHRS) and the
track follows it; refusals that do not agree (corrupt samples among good ones) never are.

Between samples the attitude is interpolated, after the newest one extrapolated with its body
rates, and either carries `gap_var`: what the vehicle may have turned that the samples do not
show, so an attitude held through a silence of the autopilot stops being trusted as it ages.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable

import numpy as np

from daemon.fusion.sensors import Attitude
from daemon.fusion.state import matrix_to_rotvec, rotvec_to_matrix
from daemon.fusion.stream_health import StreamHealth

MAX_RATE_RAD_S = 10.0  # beyond ArduCopter's ACRO flips (ACRO_RP_RATE 360 deg/s)
NOISE_RAD = 0.02  # an AHRS's attitude noise between two samples, generously
# ArduCopter's default roll/pitch acceleration limit, ATC_ACCEL_R_MAX / ATC_ACCEL_P_MAX 110000
# cdeg/s^2 (ArduPilot libraries/AC_AttitudeControl/AC_AttitudeControl.h,
# AC_ATTITUDE_CONTROL_ACCEL_RP_MAX_DEFAULT_CDSS): taken as the 3-sigma bound of a turn's change
MAX_ANGULAR_ACCEL = np.radians(1100.0)
TILT_NOISE_RAD = np.radians(2.0)  # two AHRS tilts a sample apart, noise and rounding, generously
STRIKES = 5
GRAVITY_DOWN = np.array([0.0, 0.0, 1.0])


def turned(sample: Attitude, dt: float) -> np.ndarray:
    """R_n_b of `sample` carried `dt` seconds on by its body rates."""
    return sample.R_n_b @ rotvec_to_matrix(sample.rates * dt)


def unseen_turn_var(extrapolated_s: float, interpolated_s: float = 0.0) -> float:
    """Variance (rad^2 per axis) of the turn an attitude `extrapolated_s` past a sample by its
    rates, or interpolated between samples `interpolated_s` apart, cannot know: half (a
    quarter of the interval, for an interpolation) of the angular acceleration times the time
    squared, with MAX_ANGULAR_ACCEL as 3 sigma."""
    sigma = MAX_ANGULAR_ACCEL / 3.0 * (0.5 * extrapolated_s**2 + 0.125 * interpolated_s**2)
    return float(sigma**2)


class AttitudeTrack:
    """ATTITUDE samples sorted by time (arrival order does not matter), kept for `keep_s`;
    `report(text)` hears when the stream keeps being refused (stream_health.py) and when it is
    consistent again."""

    def __init__(self, timeout_s: float, keep_s: float,
                 report: Callable[[str], None] | None = None):
        self.timeout_s = timeout_s
        self.keep_s = keep_s
        self.times: list[float] = []
        self.samples: list[Attitude] = []
        self.refused = 0
        self._change: list[Attitude] = []  # refused in a row, each agreeing with the one before
        # the last pair interpolated between and its relative rotation: the filter asks for
        # several times between the same two samples (4 in 5 of the asks in a survey)
        self._between: tuple[Attitude, Attitude, np.ndarray] | None = None
        self.health = StreamHealth("ATTITUDE", "doubted", "refused samples are not used; check "
                                   "the autopilot's AHRS and the link", report)

    def add(self, sample: Attitude) -> bool:
        """Insert a sample in time order and forget those older than keep_s; False (and not
        kept) when it cannot be the vehicle's attitude next to its neighbours."""
        kept = self._admit(sample)
        self.health.verdict(sample.t, kept)
        if not kept:
            self.refused += 1
            return False
        i = bisect.bisect_right(self.times, sample.t)
        self.times.insert(i, sample.t)
        self.samples.insert(i, sample)
        cut = bisect.bisect_left(self.times, self.times[-1] - self.keep_s)
        if cut:
            del self.times[:cut], self.samples[:cut]
        return True

    def _admit(self, sample: Attitude) -> bool:
        """Plausible next to the kept samples, or the STRIKES-th of refused samples in a row
        that agree with each other (a real change)."""
        if not self._plausible(sample, self.times, self.samples):
            last = self._change[-1:]
            agrees = bool(last) and self._plausible(sample, [last[0].t], last)
            self._change = [*self._change, sample] if agrees else [sample]
            if len(self._change) < STRIKES:
                return False
        self._change = []
        return True

    @staticmethod
    def _plausible(sample: Attitude, times: list[float], kept: list[Attitude]) -> bool:
        """Whether `sample` can follow or precede its nearest neighbour in time among `kept`
        (sorted by time, at `times`)."""
        if float(np.max(np.abs(sample.rates))) > MAX_RATE_RAD_S:
            return False
        i = bisect.bisect_right(times, sample.t)
        near = min((kept[j] for j in (i - 1, i) if 0 <= j < len(kept)),
                   key=lambda s: abs(s.t - sample.t), default=None)
        if near is None:
            return True
        dt = sample.t - near.t
        whole = float(np.linalg.norm(matrix_to_rotvec(near.R_n_b.T @ sample.R_n_b)))
        if whole > NOISE_RAD + MAX_RATE_RAD_S * abs(dt):
            return False
        mean = Attitude(near.t, near.R_n_b, 0.5 * (near.rates + sample.rates))
        expected = turned(mean, dt).T @ GRAVITY_DOWN
        seen = sample.R_n_b.T @ GRAVITY_DOWN
        tilt = float(np.arccos(np.clip(expected @ seen, -1.0, 1.0)))
        return tilt <= TILT_NOISE_RAD + 0.25 * MAX_ANGULAR_ACCEL * dt**2

    def at(self, t: float) -> Attitude | None:
        """The attitude at time t: interpolated between neighbours, or the nearest sample
        carried to t by its rates when it is within the timeout (None when there is none close
        enough), with the variance of what the vehicle may have turned meanwhile."""
        i = bisect.bisect_right(self.times, t)
        before = self.samples[i - 1] if i > 0 else None
        after = self.samples[i] if i < len(self.samples) else None
        if before is not None and after is not None and after.t - before.t <= 2 * self.timeout_s:
            gap = after.t - before.t
            alpha = (t - before.t) / gap if gap > 0 else 0.0
            R = before.R_n_b @ rotvec_to_matrix(alpha * self._turn_between(before, after))
            rates = (1 - alpha) * before.rates + alpha * after.rates
            return Attitude(t, R, rates, unseen_turn_var(0.0, gap))
        near = min((s for s in (before, after) if s is not None),
                   key=lambda s: abs(s.t - t), default=None)
        if near is None or abs(near.t - t) > self.timeout_s:
            return None
        return Attitude(t, turned(near, t - near.t), near.rates, unseen_turn_var(t - near.t))

    def _turn_between(self, before: Attitude, after: Attitude) -> np.ndarray:
        """The rotation vector from `before` to `after` (body axes), kept for the next ask."""
        kept = self._between
        if kept is None or kept[0] is not before or kept[1] is not after:
            kept = self._between = (before, after,
                                    matrix_to_rotvec(before.R_n_b.T @ after.R_n_b))
        return kept[2]

    @property
    def latest(self) -> Attitude | None:
        """The newest sample, if any."""
        return self.samples[-1] if self.samples else None
