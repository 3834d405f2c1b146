"""Obstacle distances around the vehicle from a depth image, as the autopilot's proximity
and avoidance read them: OBSTACLE_DISTANCE, 72 sectors of 5 degrees.

How the autopilots read the message (so this is what we send):
- ArduPilot (PRX1_TYPE = 2, MAVLink; libraries/AP_Proximity/AP_Proximity_MAV.cpp): the
  sector width is `increment_f` if non-zero, else `increment`; element j lies at
  j * increment + angle_offset (+ PRX1_YAW_CORR) degrees clockwise from the nose; a distance
  of 0, 65535, or outside [min_distance, max_distance] is ignored; `frame` is not read
  (body frame assumed); data older than 500 ms is dropped.
- PX4 (collision prevention, CP_DIST > 0; src/lib/collision_prevention/CollisionPrevention.cpp
  and ObstacleMath.cpp): `frame` must be MAV_FRAME_BODY_FRD (or a north-aligned one), bins are
  centred on i * increment + angle_offset; UINT16_MAX is "no data" (with CP_GO_NO_DATA = 0
  the vehicle will not move that way), a distance >= max_distance "nothing in range"; data
  older than RANGE_STREAM_TIMEOUT_US (500 ms) is dropped.
- MAVLink common.xml: distances in cm; max_distance + 1 = no obstacle; UINT16_MAX = unknown.

So: frame BODY_FRD, increment 5 (and increment_f 5.0), angle_offset 0, sector j centred on
j * 5 degrees clockwise from the nose (seen from above). A sector the camera sees gets the
horizontal distance from the vehicle's centre to the nearest obstacle in it (the k-th nearest
point, so that single noisy pixels do not count), or max_distance + 1 when the depth camera
measured only farther surfaces; every other sector (outside the camera's view, holes,
nothing measured) says UINT16_MAX. An obstacle is whatever is within `band_m` above or
below the vehicle's horizontal plane (levelled with the autopilot's roll and pitch when
given): the ground and ceiling farther away do not count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from calib.camera import CameraModel
from calib.depth_camera import decimate, points_from_depth, unit_depth_rays
from daemon.messages import usec
from daemon.mounting import rotation_zyx

SECTORS = 72
INCREMENT_DEG = 360.0 / SECTORS
UNKNOWN = 65535  # UINT16_MAX: no data for the sector


@dataclass(frozen=True)
class ObstacleSettings:
    """What counts as an obstacle and how sure a sector must be (lengths in metres)."""

    min_m: float = 0.3  # the depth camera's minimum range: nearer obstacles read as this
    max_m: float = 8.0  # farthest obstacle reported (at most the depth camera's range)
    band_m: float = 0.5  # obstacles are within this height of the vehicle's level plane
    min_points: int = 8  # a sector with fewer measured points says UNKNOWN
    nearest_rank: int = 5  # a sector's distance is its k-th nearest point (noise specks)
    decimate: int = 4  # depth averaged over blocks of this many pixels square first


@dataclass
class ObstacleScan:
    """One OBSTACLE_DISTANCE's content: distances (72,) in cm, the range in cm."""

    t: float
    distances_cm: np.ndarray
    min_cm: int
    max_cm: int

    def distance_m(self, sector: int) -> float | None:
        """Metres to the obstacle in a sector; inf for no obstacle, None for unknown."""
        d = int(self.distances_cm[sector])
        if d == UNKNOWN:
            return None
        return np.inf if d > self.max_cm else d / 100.0


class ObstacleDistances:
    """Turns depth images of a camera mounted on the vehicle into ObstacleScans."""

    def __init__(self, camera: CameraModel, T_b_c: np.ndarray,
                 settings: ObstacleSettings | None = None):
        """`T_b_c`: body-from-camera (4x4; body FRD, the camera's mounting and lever arm)."""
        self.settings = settings or ObstacleSettings()
        self.camera = camera
        self.T_b_c = np.asarray(T_b_c, dtype=np.float64)
        small = camera.scaled(1.0 / self.settings.decimate)
        self._rays = unit_depth_rays(small)

    def scan(self, depth: np.ndarray, t: float,
             roll_pitch: tuple[float, float] | None = None) -> ObstacleScan:
        """The sectors seen in a depth map (float32 m, 0/NaN = none) captured at time t;
        `roll_pitch` (rad, the autopilot's attitude) levels the obstacle band."""
        s = self.settings
        small, camera = decimate(depth, self.camera, s.decimate)
        points, _ = points_from_depth(small, camera, self._rays)
        body = points @ self.T_b_c[:3, :3].T + self.T_b_c[:3, 3]
        if roll_pitch is not None:
            body = body @ rotation_zyx(roll_pitch[0], roll_pitch[1], 0.0).T
        body = body[np.abs(body[:, 2]) <= s.band_m]
        distance = np.hypot(body[:, 0], body[:, 1])
        angle = np.degrees(np.arctan2(body[:, 1], body[:, 0]))
        sector = np.rint(angle / INCREMENT_DEG).astype(np.int64) % SECTORS
        min_cm, max_cm = round(s.min_m * 100), round(s.max_m * 100)
        out = np.full(SECTORS, UNKNOWN, np.uint16)
        order = np.lexsort((distance, sector))
        sector, distance = sector[order], distance[order]
        starts = np.searchsorted(sector, np.arange(SECTORS))
        counts = np.searchsorted(sector, np.arange(SECTORS), "right") - starts
        for j in np.flatnonzero(counts >= s.min_points):
            d = distance[starts[j] + min(s.nearest_rank, counts[j]) - 1]
            out[j] = max_cm + 1 if d > s.max_m else min(max(round(d * 100), min_cm), max_cm)
        return ObstacleScan(t, out, min_cm, max_cm)


def obstacle_distance(mav: mavlink2.MAVLink, scan: ObstacleScan) -> object:
    """OBSTACLE_DISTANCE in the body frame (see the module docstring), stamped at capture."""
    return mav.obstacle_distance_encode(
        usec(scan.t), mavlink2.MAV_DISTANCE_SENSOR_INFRARED,
        [int(d) for d in scan.distances_cm], int(INCREMENT_DEG), scan.min_cm, scan.max_cm,
        increment_f=INCREMENT_DEG, angle_offset=0.0, frame=mavlink2.MAV_FRAME_BODY_FRD)
