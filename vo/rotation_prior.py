"""The camera's turn between frames from outside the images (rotation prior).

A downward camera over flat ground cannot tell a small tilt from a small sideways move: both
shift the image alike, and the pose refinement trades one for the other, the map drifting with
it. The autopilot knows how the vehicle turned (its gyros, through its attitude): given the
camera's orientation in any fixed frame at each frame (`Orientation`, e.g. the autopilot's
attitude times the camera mounting), the turn since the last tracked frame starts the image
alignment and pulls the pose refinement with the information 1 / (std^2 + both variances).
A frame whose image alignment turned further than the gate from the prior does not use it
(the mounting or the clock is wrong): the result says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vo.se3 import rotation_angle_deg


@dataclass(frozen=True)
class Orientation:
    """The camera's orientation R_x_c (camera axes in a fixed frame x) at a frame's time and
    the variance (rad^2 per axis) of what it may have missed since its source's samples."""

    R_x_c: np.ndarray
    var: float = 0.0


def relative_prior(orientation: Orientation | None, last: Orientation | None,
                   last_R_c_w: np.ndarray, std_deg: float) -> tuple[np.ndarray, float] | None:
    """(R_c_w prior, information 1/rad^2) of a frame from its orientation and the last
    tracked frame's (its rotation last_R_c_w); None without both or with the prior off."""
    if orientation is None or last is None or std_deg <= 0:
        return None
    R_rel = orientation.R_x_c.T @ last.R_x_c  # R_ck_clast
    var = np.radians(std_deg) ** 2 + orientation.var + last.var
    return R_rel @ last_R_c_w, 1.0 / var


def agrees(R_c_w: np.ndarray, R_prior: np.ndarray, gate_deg: float) -> bool:
    """Whether an image-aligned rotation is within the gate of the prior."""
    return rotation_angle_deg(R_c_w @ R_prior.T) <= gate_deg
