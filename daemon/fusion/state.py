"""The navigation filter: an error-state-style EKF, written out (its prediction holds the IMU
sample between steps and its updates are gated Schmidt updates that filterpy's EKF does not do).

State (NED local frame N, metres): vehicle position p and velocity v, accelerometer bias b_a
(body), the camera position a at the anchor of the current map segment, ln(scale), a small
rotation theta that corrects the nominal alignment R_N_w (tracker world -> N), the ground level
under the rangefinder, the barometer's offset, the tracker's slowly wandering tilt error
delta (rotation about N's north and east axes, rad) and the time offset between the
autopilot's stamps, mapped to our clock, and the camera's (s): the filter holds the vehicle in
the autopilot's time, the map sees it in the camera's (at_camera_time). Unknown, it is a
motion misplaced in time that the filter took for scale (0.1 % per ms in a climb); estimated
from the motion's changes as a state of the filter, as M. Li and A. Mourikis do for a
camera-IMU offset ("Online temporal calibration for camera-IMU systems", IJRR 2014; also
VINS-Mono's td, Qin and Shen, arXiv 1808.00692).

The tracker sees the camera at p_w = p_w0 + exp(-ln_s) R_w_N (p + R_N_b o - a), with p_w0 its
own position at the anchor and o the camera's lever arm: this is the similarity between the
tracker's world and NED, with the anchor cloned from the vehicle position when a segment starts
(so a new map keeps the vehicle where it was). theta is folded into R_nom after every update.

The tracker's errors are not white at the frame rate. Over a flat scene its tilt trades off
against its translation: a tilt error wanders over about a second, and its position error
follows it (height x tilt), most of what is left after a Sim(3) fit of the whole map. Fused as
white noise, that is averaged over 30 frames a second as if independent, and the filter becomes
several times too confident, scale included. delta is that tilt error, a
first-order Gauss-Markov process (vo_tilt_error_std_deg, vo_error_time_s); its effect on the
position is the tracker's own regression of position on rotation (its covariance), and the
autopilot's attitude observes it.
"""

from __future__ import annotations

import enum

import numpy as np

from daemon.fusion.accel_scale import AccelScale
from daemon.fusion.climb_scale import ClimbScale
from daemon.fusion.config import FusionConfig
from vo.se3 import exp_so3, rotvec

POS, VEL, BIAS, ANCHOR, THETA = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12),
                                 slice(13, 16))
LOG_SCALE, GROUND, BARO = 12, 16, 17
VO_TILT = slice(18, 20)  # about N's north and east axes: the tracker's heading does not trade
# off against its position over a flat scene below
TIME_OFFSET = 20  # the autopilot's stamps, mapped to our clock, minus the truth (s)
DIM = 21
GRAVITY_N = np.array([0.0, 0.0, 9.80665])
HEADING = 15  # theta's z component: rotation about N's down axis


def skew(v: np.ndarray) -> np.ndarray:
    """[v]x, the cross-product matrix."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """exp([v]x): the rotation matrix of a rotation vector."""
    return exp_so3(np.asarray(v, dtype=np.float64))


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """log(R) as a rotation vector."""
    return rotvec(np.asarray(R, dtype=np.float64))


class ScaleSource(enum.Enum):
    """Where the current map's scale came from."""

    PRIOR = "prior"  # the wide prior: the filter's own scale is not trusted (forget_scale)
    GIVEN = "given"  # start_segment's, e.g. from the rangefinder
    FIT = "fit"  # an independent fit (rescale: climb against the barometer, IMU motion)
    METRIC = "metric"  # a map started from depth: metres, ln(scale) 0 with no variance


class NavFilter:
    """State, covariance and the nominal quantities around which the EKF is linearised."""

    def __init__(self, cfg: FusionConfig):
        self.cfg = cfg
        self.x = np.zeros(DIM)  # the state vector (see the module docstring for its layout)
        self.P = np.eye(DIM)  # its covariance
        self.t: float | None = None
        self.R_nom = np.eye(3)  # R_N_w
        self.p_w0 = np.zeros(3)
        self.has_ground = False
        self.has_baro = False
        self.segment = -1  # id of the map segment the anchor belongs to
        # where the segment was hung when it started: (camera in N, its covariance, the map's
        # point there), before any re-hanging on dead reckoning (measurements.update_from_start)
        self.segment_start: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.realigns = 0  # segments restarted because the tracker's poses stopped fitting
        self.converged = False  # scale and heading of this segment passed the alignment gate
        self.scale_source = ScaleSource.PRIOR
        self.scene_ne: np.ndarray | None = None  # where the map's height was last fused
        self.climb = ClimbScale()  # the current map's heights against the barometer's
        self.motion = self._accel_scale()  # its displacement against the IMU's
        self.accel: np.ndarray | None = None  # last IMU specific force, held until the next
        self.t_accel = float("-inf")
        self.rejections = {"range": 0, "baro": 0, "vo": 0}
        # (time, tracker position - the filter's, metres N) of the tracker updates rejected in a
        # row: what the filter and the map disagree by until one of them is believed again
        self.vo_disagreement: list[tuple[float, np.ndarray]] = []
        self.lever = np.array([cfg.camera_x_m, cfg.camera_y_m, cfg.camera_z_m])

    @property
    def scale(self) -> float:
        """Metres per tracker unit of the current map."""
        return float(np.exp(self.x[LOG_SCALE]))

    def _accel_scale(self) -> AccelScale:
        cfg = self.cfg
        return AccelScale(cfg.accel_noise, cfg.vo_position_std_m)

    def reset(self) -> None:
        """Forget everything, as constructed (others keep their reference to this filter)."""
        self.__init__(self.cfg)

    @property
    def diverged(self) -> bool:
        """The state or covariance is no longer a number, or a variance went negative."""
        return not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.P))
                    and np.all(np.diag(self.P) >= 0.0))

    def snapshot(self) -> tuple:
        """Everything needed to continue the filter from here."""
        return (self.t, self.x.copy(), self.P.copy(), self.R_nom.copy(), self.p_w0.copy(),
                self.has_ground, self.has_baro, dict(self.rejections), self.segment,
                self.accel, self.t_accel, self.realigns, self.converged, self.scale_source,
                self.scene_ne, self.climb.copy(), self.motion.copy(), list(self.vo_disagreement),
                self.segment_start)

    def restore(self, snap: tuple) -> None:
        """Go back to a snapshot."""
        (self.t, x, P, R_nom, p_w0, self.has_ground, self.has_baro, rejections, self.segment,
         self.accel, self.t_accel, self.realigns, self.converged, self.scale_source,
         self.scene_ne, climb, motion, disagreement, self.segment_start) = snap
        self.vo_disagreement = list(disagreement)
        self.x, self.P = x.copy(), P.copy()
        self.climb, self.motion = climb.copy(), motion.copy()
        self.R_nom, self.p_w0, self.rejections = R_nom.copy(), p_w0.copy(), dict(rejections)

    # --- initialisation -----------------------------------------------------------------------

    def start(self, t: float, velocity_std: float, height_z: float = 0.0) -> None:
        """First use: the vehicle where the local frame starts, above its origin at the
        autopilot's own height `height_z` (NED z), still within `velocity_std`."""
        cfg = self.cfg
        self.t = t
        self.x = np.zeros(DIM)
        self.x[2] = height_z
        self.x[LOG_SCALE] = np.log(cfg.initial_scale)
        var = np.zeros(DIM)
        var[POS] = 1e-6
        var[VEL] = velocity_std**2
        var[BIAS] = cfg.accel_bias_std**2
        var[ANCHOR] = 1e-6
        var[LOG_SCALE] = cfg.scale_prior_std**2
        var[THETA] = 1.0
        var[GROUND] = var[BARO] = 1.0
        var[VO_TILT] = np.radians(cfg.vo_tilt_error_std_deg) ** 2
        var[TIME_OFFSET] = cfg.time_offset_std_s**2
        self.P = np.diag(var)

    def start_segment(self, p_w: np.ndarray, R_w_b: np.ndarray, R_n_b: np.ndarray,
                      log_scale: float, scale_std: float | None = None,
                      metric: bool = False, source: ScaleSource | None = None,
                      same_map: bool = False) -> None:
        """A new map: clone the camera position as the anchor, fresh alignment, and the scale
        with `scale_std` (default: the prior's) from `source` (default: GIVEN with a std under
        the prior's, else PRIOR); a `metric` map's scale is 1, exactly and for good
        (ScaleSource.METRIC). `same_map`: the map re-anchored, its climb pairs kept (they are
        in its own coordinates)."""
        if metric:
            log_scale, scale_std = 0.0, 0.0
        self.converged = False
        if not same_map:
            self.climb = ClimbScale()
        self.motion = self._accel_scale()
        x, P = self.x, self.P
        self._hang_map(p_w, R_n_b)
        if not (same_map and self.scale_source is ScaleSource.PRIOR):
            # re-aligned on the wide prior, the map disagreed with the vehicle for its unknown
            # scale, not a move of its own: where it started still holds
            self.segment_start = (x[ANCHOR].copy(), P[ANCHOR, ANCHOR].copy(), self.p_w0.copy())
        x[LOG_SCALE] = log_scale
        x[THETA] = 0.0
        if scale_std is None:
            scale_std = self.cfg.scale_prior_std
        self.scale_source = (ScaleSource.METRIC if metric else source if source is not None
                             else ScaleSource.GIVEN if scale_std < self.cfg.scale_prior_std
                             else ScaleSource.PRIOR)
        for index, std in ((LOG_SCALE, scale_std),
                           (THETA, np.radians(self.cfg.attitude_std_deg)),
                           (HEADING, np.radians(self.cfg.heading_std_deg))):
            P[index, :] = 0.0
            P[:, index] = 0.0
            if isinstance(index, slice):
                P[index, index] = np.eye(3) * std**2
            else:
                P[index, index] = std**2
        self.R_nom = R_n_b @ R_w_b.T

    def at_camera_time(self) -> tuple[np.ndarray, np.ndarray]:
        """The vehicle's position (N) at the camera's clock's time of the filter, and its
        Jacobian (3 x DIM): the filter at t holds the vehicle when the autopilot's stamps,
        mapped to our clock, say t, which is TIME_OFFSET after the truth, so at the camera's t
        the vehicle is where its velocity carried it in that time. A filter that never had an
        IMU moves in the map's own time: no offset."""
        x = self.x
        J = np.zeros((3, DIM))
        J[:, POS] = np.eye(3)
        if self.accel is None:
            return x[POS].copy(), J
        offset = float(x[TIME_OFFSET])
        J[:, VEL] = offset * np.eye(3)
        J[:, TIME_OFFSET] = x[VEL]
        return x[POS] + offset * x[VEL], J

    def camera(self, R_n_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The camera's position (N) at the time of a frame fused now, and its Jacobian."""
        position, J = self.at_camera_time()
        return position + R_n_b @ self.lever, J

    def doubt_motion(self) -> None:
        """The tracker's updates were rejected in a row (vo_disagreement): the map moved, or
        the filter's own motion went wrong (a corrupt IMU or attitude sample that passed its
        checks), and nothing tells which. The position takes the last disagreement as
        covariance and the velocity its rate (a least-squares slope), so whichever was wrong,
        what is sent covers it, and the next tracker updates can correct the velocity instead
        of failing their gate against a filter sure of a wrong one. A map whose scale is the
        wide prior disagrees with any motion: no evidence against the filter's."""
        if not self.vo_disagreement or self.scale_source is ScaleSource.PRIOR:
            self.vo_disagreement = []
            return
        times = np.array([t for t, _ in self.vo_disagreement])
        apart = np.array([d for _, d in self.vo_disagreement])
        rate = np.zeros(3)
        if len(times) > 1 and np.ptp(times) > 0:
            dt = times - times.mean()
            rate = dt @ (apart - apart.mean(axis=0)) / float(dt @ dt)
        self.P[POS, POS] += np.outer(apart[-1], apart[-1])
        self.P[VEL, VEL] += np.outer(rate, rate)
        self.vo_disagreement = []

    def rescale(self, p_w: np.ndarray, R_n_b: np.ndarray, log_scale: float,
                scale_std: float, source: ScaleSource = ScaleSource.FIT) -> None:
        """Replace the scale by an independent estimate (ln, std; climb_scale.py,
        accel_scale.py; the rangefinder's first reading: GIVEN) and put the vehicle where the
        map says it is at that scale; its velocity is stretched by the same ratio, and both
        carry the new scale's error. Dead reckoning at the old scale is dropped, and so is the
        barometer's offset, which was fitted to it (the next reading re-references it)."""
        x, P = self.x, self.P
        if self.imu_carries():
            self._rescale_map(p_w, R_n_b, log_scale, scale_std, source)
            return
        ratio = float(np.exp(log_scale - x[LOG_SCALE]))
        m = self.R_nom @ (np.asarray(p_w, float) - self.p_w0)
        s = float(np.exp(log_scale))
        offset = float(x[TIME_OFFSET]) if self.accel is not None else 0.0
        velocity = ratio * x[VEL]
        # the map's position is the camera's at the frame's time, TIME_OFFSET after the
        # filter's (at_camera_time): the vehicle is where its velocity takes it back from there
        J = np.eye(DIM)
        J[POS, POS] = 0.0
        J[POS, ANCHOR] = np.eye(3)
        J[VEL, VEL] *= ratio
        J[POS, VEL] = -offset * ratio * np.eye(3)
        J[POS, TIME_OFFSET] = -velocity if self.accel is not None else 0.0
        J[LOG_SCALE, LOG_SCALE] = 0.0
        P = J @ P @ J.T
        d = np.zeros(DIM)  # the new ln(scale), and how position and velocity move with it
        d[POS], d[VEL], d[LOG_SCALE] = s * m - offset * velocity, velocity, 1.0
        P += np.outer(d, d) * scale_std**2
        P[POS, POS] += np.eye(3) * self.cfg.vo_position_std_m**2
        self.P = 0.5 * (P + P.T)
        x[POS] = x[ANCHOR] + s * m - R_n_b @ self.lever - offset * velocity
        x[VEL] = velocity
        x[LOG_SCALE] = log_scale
        self.has_baro = False
        self.scale_source = source

    def imu_carries(self) -> bool:
        """Whether the IMU (with the barometer and rangefinder) carries the vehicle, not the
        map: the scale too unsure to move it (above nav_scale_std) and an IMU to integrate."""
        return (self.accel is not None
                and np.sqrt(self.P[LOG_SCALE, LOG_SCALE]) > self.cfg.nav_scale_std)

    def _rescale_map(self, p_w: np.ndarray, R_n_b: np.ndarray, log_scale: float,
                     scale_std: float, source: ScaleSource) -> None:
        """rescale() of a filter whose IMU carries the vehicle (imu_carries): it stays, and
        the map is hung from where it is, at the new scale. The anchor had followed the old
        scale's wandering (re-anchored at it; forget_scale drops the correlation): put where
        the map said at the new scale, a vehicle 40 m into a level flight jumped 6.8 m at a
        claimed 1 m."""
        self._hang_map(p_w, R_n_b)
        P = self.P
        P[LOG_SCALE, :] = 0.0
        P[:, LOG_SCALE] = 0.0
        P[LOG_SCALE, LOG_SCALE] = scale_std**2
        self.x[LOG_SCALE] = log_scale
        self.has_baro = False
        self.scale_source = source

    def _hang_map(self, p_w: np.ndarray, R_n_b: np.ndarray) -> None:
        """Make the map's point p_w the camera's position where the filter has the vehicle:
        the anchor takes the vehicle's uncertainty, none of the scale's."""
        camera, J = self.camera(R_n_b)
        P = self.P
        JP = J @ P
        P[ANCHOR, :] = JP
        P[:, ANCHOR] = JP.T
        P[ANCHOR, ANCHOR] = JP @ J.T
        self.x[ANCHOR] = camera
        self.p_w0 = np.asarray(p_w, float).copy()

    def forget_scale(self) -> None:
        """Back to the wide prior's uncertainty: from there the EKF's linearised fixes settle
        far off and become sure of it before the estimate gets there; the fits of
        climb_scale.py and accel_scale.py give it a start without linearisation."""
        P = self.P
        P[LOG_SCALE, :] = 0.0
        P[:, LOG_SCALE] = 0.0
        P[LOG_SCALE, LOG_SCALE] = self.cfg.scale_prior_std**2

    def reanchor(self, p_w: np.ndarray, R_n_b: np.ndarray) -> None:
        """Move the anchor to where the map puts the camera now (tracker position p_w), so only
        the map's drift from here on matters. The map's own chain is followed, not the filtered
        position, so no filter lag is frozen in. The anchor is the point of N the map calls
        p_w0, not where the camera truly was then: the tracker's noise at the old anchor and
        the new one cancel along the chain, so moving adds no noise (adding the frame's noise
        at every move would make the anchor a random walk of it). While the IMU carries the
        vehicle, the map is hung from it instead: followed at a scale that is not known, the
        chain took the prior's variance at every move and the anchor's std grew to 1.6e6 m
        in 66 s (past float32 later: an ODOMETRY pymavlink could not pack)."""
        if self.imu_carries():
            self._hang_map(p_w, R_n_b)
            return
        x, P = self.x, self.P
        v = self.scale * (self.R_nom @ (np.asarray(p_w, float) - self.p_w0))
        J = np.zeros((3, DIM))
        J[:, ANCHOR] = np.eye(3)
        J[:, LOG_SCALE] = v
        J[:, THETA] = -skew(v)
        JP = J @ P
        P[ANCHOR, :] = JP
        P[:, ANCHOR] = JP.T
        P[ANCHOR, ANCHOR] = JP @ J.T
        x[ANCHOR] = x[ANCHOR] + v
        self.p_w0 = np.asarray(p_w, float).copy()

    def reference(self, which: str, value: float, std: float) -> None:
        """(Re)start the ground level ("range") or baro offset ("baro") so that the measured
        `value` (vertical distance to the ground, or altitude) fits the current height:
        both are value + p_z, with p_z's uncertainty plus the measurement's."""
        index = GROUND if which == "range" else BARO
        x, P = self.x, self.P
        x[index] = value + x[2]
        P[index, :] = P[2, :]
        P[:, index] = P[:, 2]
        P[index, index] = P[2, 2] + std**2
        setattr(self, "has_ground" if which == "range" else "has_baro", True)
        self.rejections[which] = 0

    # --- prediction ---------------------------------------------------------------------------

    def predict(self, t: float, accel: np.ndarray | None, R_n_b: np.ndarray | None,
                accel_noise: float | None = None) -> None:
        """Propagate to time t: with the IMU's specific force (held since its sample) and the
        attitude when both are given, its white noise `accel_noise` (m/s^2/sqrt(Hz) along each
        body axis; default the configured one on all three), else with a constant-velocity
        model."""
        dt = t - self.t
        if dt <= 0:
            return
        cfg = self.cfg
        x = self.x
        F = np.eye(DIM)
        F[POS, VEL] = np.eye(3) * dt
        F[VO_TILT, VO_TILT] = np.eye(2) * self._tilt_decay(dt)
        if accel is not None and R_n_b is not None:
            acc = R_n_b @ (accel - x[BIAS]) + GRAVITY_N
            F[POS, BIAS] = -0.5 * R_n_b * dt**2
            F[VEL, BIAS] = -R_n_b * dt
            density = np.broadcast_to(cfg.accel_noise if accel_noise is None else accel_noise,
                                      (3,))
            q = R_n_b @ np.diag(density**2) @ R_n_b.T  # body axes into N
        else:
            acc = np.zeros(3)
            q = np.eye(3) * cfg.motion_accel_std**2
        speed = float(np.linalg.norm(x[VEL]))
        horizontal_speed = float(np.linalg.norm(x[3:5]))
        x[POS] += x[VEL] * dt + 0.5 * acc * dt**2
        x[VEL] += acc * dt
        if accel is not None and R_n_b is not None:  # independent of the filter's bias,
            self.motion.integrate(dt, R_n_b @ accel + GRAVITY_N)  # which a wrong scale skews
        else:
            self.motion.interrupt()
        x[VO_TILT] *= self._tilt_decay(dt)
        Q = self._process_noise(dt, q, speed, horizontal_speed, accel is not None)
        self.P = F @ self.P @ F.T + Q
        self.t = t

    def _process_noise(self, dt: float, q: np.ndarray, speed: float, horizontal_speed: float,
                       imu: bool) -> np.ndarray:
        cfg = self.cfg
        Q = np.zeros((DIM, DIM))
        Q[POS, POS] = q * dt**3 / 3  # q: white acceleration noise density^2 (3x3, N)
        Q[POS, VEL] = Q[VEL, POS] = q * dt**2 / 2
        Q[VEL, VEL] = q * dt
        if imu:
            Q[BIAS, BIAS] = np.eye(3) * cfg.accel_bias_walk**2 * dt
        Q[ANCHOR, ANCHOR] = np.eye(3) * (cfg.vo_drift_m_per_sqrt_m**2 * horizontal_speed
                                         + cfg.vo_drift_m_per_sqrt_s**2) * dt
        climb_speed = abs(self.x[5])
        sideways = slice(ANCHOR.start, ANCHOR.start + 2)  # a climb's height gives the scale
        Q[sideways, sideways] += np.eye(2) * cfg.vo_drift_climb_m_per_sqrt_m**2 * climb_speed * dt
        if self.scale_source is not ScaleSource.METRIC:
            Q[LOG_SCALE, LOG_SCALE] = (cfg.scale_walk_per_sqrt_m**2 * horizontal_speed
                                       + cfg.scale_walk_climb_per_sqrt_m**2 * climb_speed) * dt
        Q[THETA, THETA] = np.eye(3) * np.radians(cfg.alignment_walk_deg_per_sqrt_m) ** 2 * (
            speed * dt)
        Q[GROUND, GROUND] = cfg.ground_walk_m_per_sqrt_m**2 * horizontal_speed * dt
        Q[BARO, BARO] = cfg.baro_walk_m_per_sqrt_s**2 * dt
        Q[VO_TILT, VO_TILT] = np.eye(2) * np.radians(cfg.vo_tilt_error_std_deg) ** 2 * (
            1.0 - self._tilt_decay(dt) ** 2)
        Q[TIME_OFFSET, TIME_OFFSET] = cfg.time_offset_walk_s_per_sqrt_s**2 * dt
        return Q

    def _tilt_decay(self, dt: float) -> float:
        return float(np.exp(-dt / self.cfg.vo_error_time_s))
