"""ArduPilot's AP_VisualOdom: the VISO_TYPE backends between the MAVLink vision messages and
EKF3 (libraries/AP_VisualOdom: AP_VisualOdom.cpp, AP_VisualOdom_Backend.cpp,
AP_VisualOdom_MAV.cpp, AP_VisualOdom_IntelT265.cpp, upstream mid-2025).

- every type: position times VISO_SCALE; posErr/angErr clamped to [VISO_POS_M_NSE, 100] and
  [VISO_YAW_M_NSE, 1.5]; used only when quality >= VISO_QUAL_MIN; healthy while a message came
  in the last 300 ms; a reset_counter change gives the EKF a new reset time.
- type 2 (IntelT265) and 3 (VOXL): the first time the AHRS yaw is initialised (and the EKF does
  not take its yaw from external nav) the sensor's yaw is turned onto the AHRS's, keeping the
  current position ("VisOdom: yaw shifted ..."); VISO_ORIENT turns the attitude only; pre-arm
  compares roll/pitch and yaw with the AHRS (10 deg).
- type 2: data is ignored for 1 s after VISION_POSITION_ESTIMATE/ODOMETRY's reset_counter
  changes (the first message is compared with 0).
- type 3: when reset_counter differs from the last one (0 at boot) the yaw is re-aligned to the
  AHRS and the position to the last position sent to the EKF ((0,0,0) before any):
  "VisOdom: reset".
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from scipy.spatial.transform import Rotation

from sim.autopilot.gcs_vision import PoseSample, VelocitySample
from sim.autopilot.param_store import ParamStore
from sim.autopilot.records import Severity

TIMEOUT_S = 0.3  # AP_VISUALODOM_TIMEOUT_MS
RESET_IGNORE_S = 1.0  # VISUALODOM_RESET_IGNORE_DURATION_MS
ATTITUDE_CHECK_DEG = 10.0
ORIENTATIONS = {0: None, 2: ("z", 90), 4: ("z", 180), 6: ("z", 270), 24: ("y", 90),
                25: ("y", 270)}  # VISO_ORIENT values -> ArduPilot Rotation enum


class VisoType(IntEnum):
    NONE = 0
    MAV = 1
    INTEL_T265 = 2
    VOXL = 3


@dataclass(frozen=True)
class ExtNavPose:
    """What AP_VisualOdom hands EKF3's writeExtNavData."""

    time_s: float
    position: np.ndarray
    attitude: Rotation
    pos_err: float
    ang_err: float
    delay_s: float
    reset_time_s: float


@dataclass(frozen=True)
class ExtNavVelocity:
    time_s: float
    velocity: np.ndarray
    err: float
    delay_s: float


@dataclass
class Ahrs:
    """The view of the AHRS the backends use."""

    attitude: Rotation | None = None
    yaw_initialised: bool = False
    using_extnav_for_yaw: bool = False


class VisualOdom:
    """One autopilot's AP_VisualOdom; `say(severity, text)` sends a STATUSTEXT."""

    def __init__(self, params: ParamStore, ahrs: Ahrs, say) -> None:
        self.params = params
        self.ahrs = ahrs
        self.say = say
        self.type = VisoType(int(params.get("VISO_TYPE")))  # reboot required: boot value
        self.last_update = -np.inf
        self.attitude_last: Rotation | None = None
        self._last_reset_counter = 0  # AP_VisualOdom_Backend: reset timestamp bookkeeping
        self._reset_time = 0.0
        self._align_yaw = True
        self._yaw_trim = 0.0
        self._pos_correction = np.zeros(3)
        self._pos_reset_counter = 0  # type 2's ignore bookkeeping
        self._ignore_since: float | None = None
        self._voxl_counter = 0
        self._voxl_position = np.zeros(3)

    @property
    def enabled(self) -> bool:
        return self.type is not VisoType.NONE

    def healthy(self, now: float) -> bool:
        return self.enabled and now - self.last_update < TIMEOUT_S

    def _reset_timestamp(self, reset_counter: int, now: float) -> float:
        if reset_counter != self._last_reset_counter:
            self._last_reset_counter = reset_counter
            self._reset_time = now
        return self._reset_time

    def _noise(self, sample: PoseSample) -> tuple[float, float]:
        pos_err = min(max(sample.pos_err, self.params.get("VISO_POS_M_NSE")), 100.0)
        ang_err = min(max(sample.ang_err, self.params.get("VISO_YAW_M_NSE")), 1.5)
        return pos_err, ang_err

    def handle_pose(self, sample: PoseSample, now: float) -> ExtNavPose | None:
        """The pose for the EKF, or None when the backend does not pass it on."""
        if not self.enabled:
            return None
        position = sample.position * self.params.get("VISO_SCALE")
        attitude = sample.attitude
        if self.type is not VisoType.MAV:
            position, attitude = self._turn_to_vehicle(position, attitude, sample, now)
        pos_err, ang_err = self._noise(sample)
        consume = (self._should_consume(True, sample.reset_counter, now)
                   and sample.quality >= self.params.get("VISO_QUAL_MIN"))
        self.attitude_last = attitude
        self.last_update = now
        if not consume:
            return None
        return ExtNavPose(sample.time_s, position, attitude, pos_err, ang_err,
                          self.params.get("VISO_DELAY_MS") / 1000.0,
                          self._reset_timestamp(sample.reset_counter, now))

    def handle_velocity(self, sample: VelocitySample, now: float) -> ExtNavVelocity | None:
        if not self.enabled:
            return None
        velocity = sample.velocity
        if self.type is not VisoType.MAV:
            velocity = self._posvel_rotation().apply(velocity)
        consume = (self._should_consume(False, sample.reset_counter, now)
                   and sample.quality >= self.params.get("VISO_QUAL_MIN"))
        self.last_update = now
        if not consume:
            return None
        return ExtNavVelocity(sample.time_s, velocity, self.params.get("VISO_VEL_M_NSE"),
                              self.params.get("VISO_DELAY_MS") / 1000.0)

    def _turn_to_vehicle(self, position: np.ndarray, attitude: Rotation, sample: PoseSample,
                         now: float) -> tuple[np.ndarray, Rotation]:
        """Types 2/3: VOXL reset handling, yaw alignment, then rotation and correction."""
        if self.type is VisoType.VOXL and sample.reset_counter != self._voxl_counter:
            self.say(Severity.WARNING, "VisOdom: reset")
            self._align_yaw_to_ahrs(position, attitude)
            self._align_position(position, self._voxl_position)
            self._voxl_counter = sample.reset_counter
        if self._align_yaw and self._align_yaw_to_ahrs(position, attitude):
            self._align_yaw = False
        turned = self._correct(position)
        attitude = self._rotate_attitude(attitude)
        if self.type is VisoType.VOXL:
            self._voxl_position = turned
            self._voxl_counter = sample.reset_counter
        return turned, attitude

    def _posvel_rotation(self) -> Rotation:
        return Rotation.from_euler("z", self._yaw_trim)

    def _correct(self, position: np.ndarray) -> np.ndarray:
        return self._posvel_rotation().apply(position) + self._pos_correction

    def _orientation(self) -> Rotation | None:
        spec = ORIENTATIONS.get(int(self.params.get("VISO_ORIENT")))
        return None if spec is None else Rotation.from_euler(spec[0], spec[1], degrees=True)

    def _rotate_attitude(self, attitude: Rotation) -> Rotation:
        orientation = self._orientation()
        if orientation is not None:
            attitude = attitude * orientation.inv()
        return self._posvel_rotation() * attitude

    def _align_yaw_to_ahrs(self, position: np.ndarray, attitude: Rotation) -> bool:
        """Turn the sensor's yaw onto the AHRS's, keeping the current position; False while the
        AHRS yaw is not initialised or the EKF uses external nav for yaw."""
        if self.ahrs.using_extnav_for_yaw or not self.ahrs.yaw_initialised:
            return False
        orientation = self._orientation()
        corrected = attitude if orientation is None else attitude * orientation.inv()
        sensor_yaw = corrected.as_euler("ZYX")[0]
        ahrs_yaw = self.ahrs.attitude.as_euler("ZYX")[0]
        before = self._correct(position)
        trim_before = self._yaw_trim
        self._yaw_trim = float(np.mod(ahrs_yaw - sensor_yaw, 2 * np.pi))
        shift = int(np.degrees(self._yaw_trim - trim_before))
        heading = int(np.mod(np.degrees(sensor_yaw + self._yaw_trim), 360))
        self.say(Severity.INFO, f"VisOdom: yaw shifted {shift} to {heading} deg")
        self._pos_correction = self._pos_correction + before - self._correct(position)
        return True

    def _align_position(self, position: np.ndarray, new_position: np.ndarray) -> None:
        self._pos_correction = self._pos_correction + new_position - self._correct(position)

    def _should_consume(self, is_pose: bool, reset_counter: int, now: float) -> bool:
        """Type 2 ignores everything for 1 s after the pose's reset_counter changes."""
        if self.type is not VisoType.INTEL_T265:
            return True
        if is_pose and reset_counter != self._pos_reset_counter:
            self._pos_reset_counter = reset_counter
            self._ignore_since = now
        if self._ignore_since is not None and now - self._ignore_since > RESET_IGNORE_S:
            self._ignore_since = None
        return self._ignore_since is None

    def ignoring(self) -> bool:
        """Whether type 2 is in its 1 s ignore after a reset."""
        return self._ignore_since is not None

    def pre_arm_failure(self, now: float) -> str | None:
        """The text after 'PreArm: VisOdom: ', or None when the check passes."""
        if not self.enabled:
            return None
        if not self.healthy(now):
            return "not healthy"
        if self.type is VisoType.MAV:
            return None
        if self.ahrs.attitude is None or self.attitude_last is None:
            return "waiting for AHRS attitude"
        z_ahrs = self.ahrs.attitude.apply([0.0, 0.0, 1.0])
        z_sensor = self.attitude_last.apply([0.0, 0.0, 1.0])
        tilt = np.degrees(np.arccos(np.clip(np.dot(z_ahrs, z_sensor), -1.0, 1.0)))
        if tilt > ATTITUDE_CHECK_DEG:
            return f"roll/pitch diff {tilt:4.1f} deg (>10)"
        yaw = abs(np.degrees((self.ahrs.attitude.inv() * self.attitude_last).as_rotvec()[2]))
        if yaw > ATTITUDE_CHECK_DEG:
            return f"yaw diff {yaw:4.1f} deg (>10)"
        return None
