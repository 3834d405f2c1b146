"""The mount self-test: which way did the vehicle move, according to the camera?

Carry the vehicle by hand: forward along its nose, to its right, then lift it. The tracker's
motion, turned into the body frame with the configured mounting, must read FORWARD, RIGHT and
UP in turn; anything else means the mounting in the config is wrong. Motion is shown in the body
frame of the first tracked pose, in tracker units (monocular: no metres), as fractions of the
total displacement, with the heading change (turning the nose right is positive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daemon.config import MountingConfig
from daemon.mounting import body_from_camera, euler_zyx
from vo.result import Quality

AXES = (("FORWARD", "BACK"), ("RIGHT", "LEFT"), ("DOWN", "UP"))


@dataclass(frozen=True)
class MountReading:
    """Body-frame displacement since the start of the test (tracker units) and rotation."""

    displacement: np.ndarray  # forward, right, down
    roll_deg: float
    pitch_deg: float
    yaw_deg: float

    @property
    def direction(self) -> str:
        """The dominant axis with its sign, e.g. 'FORWARD' or 'UP'."""
        axis = int(np.argmax(np.abs(self.displacement)))
        return AXES[axis][0 if self.displacement[axis] > 0 else 1]

    def line(self) -> str:
        """One line for the console."""
        d = self.displacement / max(float(np.linalg.norm(self.displacement)), 1e-12)
        return (f"forward {d[0]:+.2f}  right {d[1]:+.2f}  down {d[2]:+.2f}  -> "
                f"{self.direction:<7}  (roll {self.roll_deg:+.0f}, pitch {self.pitch_deg:+.0f},"
                f" yaw {self.yaw_deg:+.0f} deg)")


class MountTest:
    """Feeds on tracker results; a reading once the motion exceeds `min_move` tracker units.
    A new map segment restarts the reference."""

    def __init__(self, mounting: MountingConfig, min_move: float = 0.1):
        self.R_c_b = body_from_camera(mounting).T
        self.min_move = min_move
        self._start: tuple[np.ndarray, np.ndarray] | None = None  # R_w_b0, p_w0

    def on_result(self, result: object) -> MountReading | None:
        """The reading for one tracker FrameResult, or None (no pose, or too little motion)."""
        if result.new_segment:
            self._start = None
        if not result.has_pose or result.quality not in (Quality.GOOD, Quality.INSUFFICIENT):
            return None
        T = np.asarray(result.T_w_c, dtype=np.float64)
        if not np.all(np.isfinite(T)):
            return None
        R_w_b = T[:3, :3] @ self.R_c_b
        if self._start is None:
            self._start = (R_w_b, T[:3, 3].copy())
            return None
        R_w_b0, p_w0 = self._start
        displacement = R_w_b0.T @ (T[:3, 3] - p_w0)
        if np.linalg.norm(displacement) < self.min_move:
            return None
        roll, pitch, yaw = np.degrees(euler_zyx(R_w_b0.T @ R_w_b))
        return MountReading(displacement, float(roll), float(pitch), float(yaw))
