"""The camera's turn between frames from outside the images (rotation prior).

A downward camera over flat ground cannot tell a small tilt from a small sideways move: both
shift the image alike, and the pose refinement trades one for the other, the map drifting with
it. The autopilot knows how the vehicle turned (its gyros, through its attitude): given the
camera's orientation in any fixed frame at each frame (`Orientation`, e.g. the autopilot's
attitude times the camera mounting), the turn since the last tracked frame starts the image
alignment and pulls the pose refinement with the information 1 / (std^2 + both variances).
A frame whose image alignment turned further than the gate from the prior does not use it
(the mounting or the clock is wrong): the result says so.

The turn between frames only keeps each step right: a map that drifts a little each frame
still tilts away over a hover (seed 10 of the closed loop: 7 degrees in 30 s, its sideways
drift of 0.7 m unseen). So a map also keeps its tilt (`TiltAnchor`): the map's world frame is
placed in the fixed frame from its first tracked frames, after which each frame's camera is
pulled towards the tilt the orientation gives it there, with the std of how far the
autopilot's tilt may wander (its heading is left free: the images hold it well, a compass
does not). The fixed frame's z axis must point down (the autopilot's NED).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from vo.se3 import exp_se3, log_so3, rotation_angle_deg

ANCHOR_FRAMES = 30  # tracked frames of a new map its world's tilt is averaged over (1 s at 30 fps)
DOWN = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Orientation:
    """The camera's orientation R_x_c (camera axes in a fixed frame x) at a frame's time and
    the variance (rad^2 per axis) of what it may have missed since its source's samples."""

    R_x_c: np.ndarray
    var: float = 0.0


Prior = tuple[np.ndarray, np.ndarray]  # (R_c_w, 3x3 information in 1/rad^2, camera frame)


def relative_prior(orientation: Orientation | None, last: Orientation | None,
                   last_R_c_w: np.ndarray, std_deg: float) -> Prior | None:
    """(R_c_w prior, information) of a frame from its orientation and the last tracked
    frame's (its rotation last_R_c_w); None without both or with the prior off."""
    if orientation is None or last is None or std_deg <= 0:
        return None
    R_rel = orientation.R_x_c.T @ last.R_x_c  # R_ck_clast
    var = np.radians(std_deg) ** 2 + orientation.var + last.var
    return R_rel @ last_R_c_w, np.eye(3) / var


class TiltAnchor:
    """The map's world frame in the orientation's fixed frame (R_x_w), the mean over the map's
    first ANCHOR_FRAMES tracked frames with an orientation; then a tilt prior for each frame."""

    def __init__(self, std_deg: float):
        self.std_deg = std_deg
        self.samples: list[np.ndarray] = []
        self.R_x_w: np.ndarray | None = None

    def add(self, orientation: Orientation | None, R_c_w: np.ndarray) -> None:
        """A tracked frame of the map (its rotation R_c_w), while the anchor is being placed."""
        if orientation is None or self.R_x_w is not None or self.std_deg <= 0:
            return
        self.samples.append(orientation.R_x_c @ R_c_w)
        if len(self.samples) >= ANCHOR_FRAMES:
            self.R_x_w = Rotation.from_matrix(np.array(self.samples)).mean().as_matrix()
            self.samples = []

    def prior(self, orientation: Orientation | None) -> Prior | None:
        """(R_c_w prior, information about the two horizontal axes only) of a frame from its
        orientation; None before the anchor is placed or without an orientation."""
        if orientation is None or self.R_x_w is None:
            return None
        down = orientation.R_x_c.T @ DOWN  # gravity's direction in the camera
        var = np.radians(self.std_deg) ** 2 + orientation.var
        return orientation.R_x_c.T @ self.R_x_w, (np.eye(3) - np.outer(down, down)) / var


def combined(a: Prior | None, b: Prior | None) -> Prior | None:
    """The one prior of two on the same rotation (to first order): information summed, the
    rotation moved from a's towards b's by b's share of it along each axis."""
    if a is None or b is None:
        return a if b is None else b
    (R_a, W_a), (R_b, W_b) = a, b
    W = W_a + W_b
    step = np.linalg.solve(W, W_b @ log_so3(R_b @ R_a.T))
    return exp_se3(np.concatenate([np.zeros(3), step]))[:3, :3] @ R_a, W



def agrees(R_c_w: np.ndarray, R_prior: np.ndarray, gate_deg: float) -> bool:
    """Whether an image-aligned rotation is within the gate of the prior."""
    return rotation_angle_deg(R_c_w @ R_prior.T) <= gate_deg
