"""OBSTACLE_DISTANCE from depth images: the message as ArduPilot and PX4 read it, sector
geometry with the camera mounting, levelling with the autopilot's attitude, and the synthetic
room against its rendered truth (acceptance: within 5% + the sensor's noise in every
sector)."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from daemon.mounting import rotation_zyx
from daemon.obstacles import (
    SECTORS,
    UNKNOWN,
    ObstacleDistances,
    ObstacleScan,
    ObstacleSettings,
    obstacle_distance,
)
from sim.synth.flight import synthetic_sequence
from sim.synth.presets import T_B_C_FORWARD

CAMERA = CameraModel(320, 240, 200.0, 200.0, 159.5, 119.5)
FORWARD = np.eye(4)
FORWARD[:3, :3] = T_B_C_FORWARD[:3, :3]  # camera z along the nose, no lever arm


def plane_depth(camera, R_level_camera, normal, offset):
    """Depth of the plane {p : normal . p = offset} (level frame, camera at the origin)."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays = camera.unproject(np.column_stack([u.ravel(), v.ravel()]).astype(float))
    along = (rays @ R_level_camera.T) @ normal
    with np.errstate(divide="ignore"):
        t = np.where(along > 1e-9, offset / along, 0.0)
    return (t * rays[:, 2]).reshape(camera.height, camera.width).astype(np.float32)


def test_message_fields_as_the_autopilots_read_them():
    distances = np.full(SECTORS, UNKNOWN, np.uint16)
    distances[[0, 1, 71]] = (250, 801, 30)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=197)
    msg = obstacle_distance(mav, ObstacleScan(12.5, distances, 30, 800))
    back = mavlink2.MAVLink(None).decode(bytearray(msg.pack(mav)))
    assert back.get_type() == "OBSTACLE_DISTANCE" and back.time_usec == 12_500_000
    assert back.frame == mavlink2.MAV_FRAME_BODY_FRD  # PX4 needs it; ArduPilot: body anyway
    assert back.increment == 5 and back.increment_f == 5.0 and back.angle_offset == 0.0
    assert (back.min_distance, back.max_distance) == (30, 800)
    assert list(back.distances[:2]) == [250, 801] and back.distances[71] == 30
    assert back.distances[2] == UNKNOWN
    scan = ObstacleScan(0.0, distances, 30, 800)
    assert (scan.distance_m(0), scan.distance_m(1), scan.distance_m(2)) == (2.5, np.inf, None)


def test_a_wall_ahead_fills_the_sectors_the_camera_sees():
    """A wall 3 m ahead, perpendicular to the nose: sector 0 (centred on the nose) reads 3 m,
    sector j the nearest point of its 5 degrees, 3 / cos(5 j - 2.5 deg); the camera's +-38.7
    deg cover sectors 64 .. 8 (the outer ones barely); the rest are unknown."""
    depth = plane_depth(CAMERA, FORWARD[:3, :3], np.array([1.0, 0, 0]), 3.0)
    scan = ObstacleDistances(CAMERA, FORWARD).scan(depth, 1.0)
    known = set(np.flatnonzero(scan.distances_cm != UNKNOWN).tolist())
    assert {*range(0, 8), *range(65, 72)} <= known <= {*range(0, 9), *range(64, 72)}
    for j in known:
        angle = max(abs(5 * ((j + 36) % 72 - 36)) - 2.5, 0.0)
        assert scan.distance_m(j) == pytest.approx(3.0 / np.cos(np.radians(angle)), rel=0.01)


def test_a_wall_to_the_right_with_a_sideways_camera():
    """The camera looking right (yaw 90 deg): a wall 2 m to the right is in sector 18."""
    right = rotation_zyx(0.0, 0.0, np.pi / 2) @ FORWARD[:3, :3]
    T = np.eye(4)
    T[:3, :3] = right
    depth = plane_depth(CAMERA, right, np.array([0, 1.0, 0]), 2.0)
    scan = ObstacleDistances(CAMERA, T).scan(depth, 1.0)
    assert scan.distance_m(18) == pytest.approx(2.0, rel=0.01)
    assert scan.distances_cm[0] == UNKNOWN and scan.distances_cm[36] == UNKNOWN


def test_the_floor_is_not_an_obstacle_once_levelled():
    """Nose 30 deg down, 1 m above the floor: in the body frame the floor ahead is within
    the band about 1.2 m away; level, it is 1 m below: nothing within the band."""
    pitch = np.radians(-30.0)
    R_level_camera = rotation_zyx(0.0, pitch, 0.0) @ FORWARD[:3, :3]
    depth = plane_depth(CAMERA, R_level_camera, np.array([0, 0, 1.0]), 1.0)
    od = ObstacleDistances(CAMERA, FORWARD)
    tilted = od.scan(depth, 0.0)
    assert 1.0 < tilted.distance_m(0) < 1.5
    level = od.scan(depth, 0.0, roll_pitch=(0.0, pitch))
    assert (level.distances_cm == UNKNOWN).all()


def test_far_measurements_say_no_obstacle_and_near_ones_the_minimum():
    depth = np.full((240, 320), 9.0, np.float32)
    depth[:, 150:170] = 0.1  # a pole closer than the camera's minimum range
    depth[:40] = np.nan  # no measurement, as some drivers say it
    od = ObstacleDistances(CAMERA, FORWARD, ObstacleSettings(min_m=0.3, max_m=8.0))
    scan = od.scan(depth, 0.0)
    assert scan.distances_cm[0] == 30  # read as the minimum, which ArduPilot keeps
    assert scan.distances_cm[5] == 801 and scan.distance_m(5) == np.inf
    assert (od.scan(np.zeros((240, 320), np.float32), 0.0).distances_cm == UNKNOWN).all()


@pytest.fixture(scope="module")
def room():
    return synthetic_sequence("room-handheld", 400)


@pytest.mark.parametrize("frame", [0, 130, 260, 390])
def test_room_sectors_match_the_rendered_truth(room, frame):
    """Acceptance: every sector reported reads the nearest obstacle of the noise-free
    rendering within 5% plus 3 sigma of the D435 model, levelled with the true attitude; it
    reports most sectors the camera sees (not those where glossy posters and edges leave too
    few measurements) and none it does not."""
    sensor = room.extras["depth_sensor"]
    T_w_b = room.extras["path"].poses(np.array([room.timestamps[frame]]))[0]
    _, pitch, roll = Rotation.from_matrix(T_w_b[:3, :3]).as_euler("ZYX")
    settings = ObstacleSettings(min_m=sensor.min_m, max_m=sensor.max_m)
    od = ObstacleDistances(room.camera, room.extras["T_b_c"], settings)
    scan = od.scan(room.depth(frame), room.timestamps[frame], roll_pitch=(roll, pitch))
    truth = rendered_truth(room, frame, (roll, pitch), settings)
    seen = np.isfinite(truth)
    known = scan.distances_cm != UNKNOWN
    assert seen.sum() >= 10 and (known & seen).sum() >= 0.6 * seen.sum()
    assert not (known & ~seen).any()
    got = scan.distances_cm[known & seen] / 100.0
    want = truth[known & seen]
    np.testing.assert_array_less(np.abs(got - want), 0.05 * want + 3 * sensor.sigma(want))


def rendered_truth(seq, frame, roll_pitch, settings):
    """Per sector, the nearest horizontal distance of the noise-free rendering's pixels
    within the band and the sensor's range (NaN where none)."""
    z = seq.image_loader.surfaces(float(seq.timestamps[frame])).depth
    u, v = np.meshgrid(np.arange(seq.camera.width), np.arange(seq.camera.height))
    rays = seq.camera.unproject(np.column_stack([u.ravel(), v.ravel()]).astype(float))
    zz = z.ravel()
    ok = (zz >= settings.min_m) & (zz <= settings.max_m)
    points = rays[ok] / rays[ok, 2:3] * zz[ok, None]
    T = seq.extras["T_b_c"]
    level = (points @ T[:3, :3].T + T[:3, 3]) @ rotation_zyx(*roll_pitch, 0.0).T
    level = level[np.abs(level[:, 2]) <= settings.band_m]
    sector = np.rint(np.degrees(np.arctan2(level[:, 1], level[:, 0])) / 5).astype(int) % 72
    out = np.full(72, np.nan)
    np.fmin.at(out, sector, np.hypot(level[:, 0], level[:, 1]))
    return out
