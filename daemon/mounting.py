"""Camera-on-vehicle rotations and the attitude conversions MAVLink needs.

Body frame FRD (x nose, y right, z down); camera x right, y down, z along the optical axis.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.config import Config, MountingConfig

# columns: camera x, y, z axes expressed in body FRD, for an optical axis along the nose
R_BODY_FORWARD_CAMERA = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
PRESET_ANGLES_DEG = {"forward": (0.0, 0.0, 0.0), "down": (0.0, -90.0, 0.0)}


def rotation_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), angles in radians (aerospace 3-2-1 order)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def body_from_camera(mounting: MountingConfig) -> np.ndarray:
    """R_b_c for a mounting preset or custom roll/pitch/yaw relative to the forward mounting."""
    if mounting.preset == "custom":
        angles = (mounting.roll_deg, mounting.pitch_deg, mounting.yaw_deg)
    else:
        angles = PRESET_ANGLES_DEG[mounting.preset]
    roll, pitch, yaw = np.radians(angles)
    return rotation_zyx(roll, pitch, yaw) @ R_BODY_FORWARD_CAMERA


def body_T_camera(config: Config) -> np.ndarray:
    """T_b_c (4x4): the mounting's rotation and the fusion's camera lever arm (metres, FRD)."""
    T_b_c = np.eye(4)
    T_b_c[:3, :3] = body_from_camera(config.mounting)
    f = config.fusion
    T_b_c[:3, 3] = (f.camera_x_m, f.camera_y_m, f.camera_z_m)
    return T_b_c


def euler_zyx(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians of a rotation matrix, 3-2-1 order."""
    yaw, pitch, roll = Rotation.from_matrix(R).as_euler("ZYX")
    return float(roll), float(pitch), float(yaw)


def quaternion_wxyz(R: np.ndarray) -> np.ndarray:
    """MAVLink quaternion order (w, x, y, z), w >= 0."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return -q if w < 0 else q


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Axis times angle (radians) of a rotation matrix."""
    return Rotation.from_matrix(R).as_rotvec()
