"""Trajectories of world-from-camera poses with timestamps, and the TUM text format."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sdvl.textfile import check_increasing, read_numeric_table

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"


@dataclass
class Trajectory:
    """Timestamped poses T_w_c: positions (N, 3) and unit quaternions (N, 4) in x y z w order."""

    t: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        q = np.asarray(self.quaternions, dtype=np.float64).reshape(-1, 4)
        self.quaternions = q / np.linalg.norm(q, axis=1, keepdims=True)

    def __len__(self) -> int:
        return self.t.size

    @property
    def rotations(self) -> Rotation:
        """The orientations as one scipy Rotation."""
        return Rotation.from_quat(self.quaternions)

    def matrices(self) -> np.ndarray:
        """(N, 4, 4) homogeneous world-from-camera matrices."""
        T = np.tile(np.eye(4), (len(self), 1, 1))
        T[:, :3, :3] = self.rotations.as_matrix()
        T[:, :3, 3] = self.positions
        return T

    @classmethod
    def from_matrices(cls, t: np.ndarray, T: np.ndarray) -> Trajectory:
        """A trajectory from times and (N, 4, 4) or (N, 3, 4) world-from-camera matrices."""
        T = np.asarray(T, dtype=np.float64)
        return cls(t, T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_quat())

    def subset(self, mask: np.ndarray) -> Trajectory:
        """The poses selected by a boolean mask or index array."""
        return Trajectory(self.t[mask], self.positions[mask], self.quaternions[mask])

    def path_length(self) -> float:
        """Distance travelled along the positions, in trajectory units."""
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file `t tx ty tz qx qy qz qw`; InputError on a malformed line."""
    data = read_numeric_table(path, 8, "t tx ty tz qx qy qz qw")
    check_increasing(data[:, 0], path)
    return Trajectory(data[:, 0], data[:, 1:4], data[:, 4:8])


def write_tum(trajectory: Trajectory, path: str | Path) -> None:
    """Write a trajectory in TUM format with full precision."""
    rows = np.column_stack([trajectory.t, trajectory.positions, trajectory.quaternions])
    np.savetxt(path, rows, fmt="%.9f", header=TUM_HEADER[2:], comments="# ")
