"""Depth input: camera.yaml's depth keys, depth-to-colour registration, association of depth
maps to frames by time, TUM RGB-D and the shared layout with depth, `sdvl render --depth`."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib.camera import CameraModel
from calib.camera_yaml import load_camera, load_depth_spec, save_camera
from calib.depth_camera import DepthSpec, decimate, register_depth
from daemon.recordings import associate
from sdvl.cli import main
from sdvl.errors import InputError
from sim.datasets import open_sequence
from sim.synth.flight import synthetic_sequence

SMALL = CameraModel(40, 30, 35.0, 35.0, 19.5, 14.5)


def test_camera_yaml_depth_keys_round_trip(tmp_path):
    depth_cam = CameraModel(48, 36, 40.0, 41.0, 23.0, 17.5, "radtan_opencv",
                            (0.01, -0.02, 0.0, 0.0, 0.0))
    T = np.eye(4)
    T[:3, 3] = (0.015, 0.0, 0.001)
    spec = DepthSpec(scale=0.0002, min_m=0.4, max_m=6.0, registered=False, camera=depth_cam,
                     T_c_d=T)
    save_camera(SMALL, tmp_path / "camera.yaml", depth=spec)
    back = load_depth_spec(tmp_path / "camera.yaml")
    assert back == spec and np.array_equal(back.T_c_d, T)
    assert load_camera(tmp_path / "camera.yaml") == SMALL
    save_camera(SMALL, tmp_path / "plain.yaml")
    assert load_depth_spec(tmp_path / "plain.yaml") is None


@pytest.mark.parametrize("depth, expected", [
    ("{scale: -1}", "depth.scale"),
    ("{scale: 0.001, units: mm}", "depth.units"),
    ("{registered: false}", "depth.camera"),
    ("{min_m: 2.0, max_m: 1.0}", "min_m < max_m"),
    ("{registered: false, camera: {width: 4, height: 3, fx: 2, fy: 2, cx: 1, cy: 1}, "
     "T_color_depth: [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}", "rigid"),
])
def test_bad_depth_keys_are_one_line_errors(tmp_path, depth, expected):
    path = tmp_path / "camera.yaml"
    path.write_text(f"width: 40\nheight: 30\nfx: 35\nfy: 35\ncx: 19.5\ncy: 14.5\n"
                    f"depth: {depth}\n")
    with pytest.raises(InputError) as err:
        load_depth_spec(path)
    assert expected in str(err.value) and "\n" not in str(err.value)
    assert str(path) in str(err.value)


def _register_reference(depth, cam_d, cam_c, T):
    """Slow and obvious: every measured depth pixel lifted, moved, projected, nearest kept."""
    out = np.zeros((cam_c.height, cam_c.width), np.float32)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            if depth[r, c] <= 0:
                continue
            ray = cam_d.unproject(np.array([[c, r]], float))[0]
            p = T[:3, :3] @ (ray / ray[2] * depth[r, c]) + T[:3, 3]
            u, v = cam_c.project(p)[0]
            cu, cv = int(np.floor(u + 0.5)), int(np.floor(v + 0.5))
            if 0 <= cu < cam_c.width and 0 <= cv < cam_c.height and p[2] > 0 \
                    and (out[cv, cu] == 0 or p[2] < out[cv, cu]):
                out[cv, cu] = p[2]
    return out


def test_registration_matches_the_slow_reference():
    rng = np.random.default_rng(4)
    cam_d = CameraModel(32, 24, 30.0, 30.0, 15.5, 11.5, "radtan_opencv", (-0.05, 0.01, 0, 0))
    depth = rng.uniform(0.5, 3.0, (24, 32)).astype(np.float32)
    depth[rng.random((24, 32)) < 0.2] = 0.0
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.02, -0.03, 0.01]))[0]
    T[:3, 3] = (0.05, -0.01, 0.02)
    fast = register_depth(depth, cam_d, SMALL, T)
    np.testing.assert_allclose(fast, _register_reference(depth, cam_d, SMALL, T), atol=1e-5)
    assert (fast > 0).mean() > 0.3


def test_registration_moves_a_plane_by_the_baseline():
    """A plane at 2 m seen by a depth camera 0.1 m to the colour camera's right: in colour
    pixels it is shifted by f * 0.1 / 2 = 1.75 px and still at 2 m."""
    depth = np.full((30, 40), 2.0, np.float32)
    T = np.eye(4)
    T[0, 3] = 0.1
    out = register_depth(depth, SMALL, SMALL, T)
    assert np.all(out[:, 2:] == pytest.approx(2.0)) and np.all(out[:, :1] == 0)


def test_to_metres_scales_gates_and_checks_the_size():
    spec = DepthSpec(scale=0.001, min_m=0.5, max_m=4.0)
    raw = np.array([[0, 400, 1000], [4000, 4001, 65535]], np.uint16)
    cam = CameraModel(3, 2, 3.0, 3.0, 1.0, 0.5)
    np.testing.assert_allclose(spec.to_metres(raw, cam), [[0, 0, 1.0], [4.0, 0, 0]])
    with pytest.raises(InputError, match="registered"):
        spec.to_metres(raw, SMALL)


def test_decimate_averages_blocks_and_drops_edges():
    depth = np.full((4, 8), 2.0, np.float32)
    depth[0, 0] = 2.04
    depth[:, 5] = 5.0  # the blocks of columns 4-5 span an edge: 2 m and 5 m
    depth[2:, 6:] = 0.0  # a block without measurements
    small, cam = decimate(depth, CameraModel(8, 4, 8.0, 8.0, 3.5, 1.5), 2)
    assert small.shape == (2, 4) and (cam.width, cam.height) == (4, 2)
    assert small[0, 0] == pytest.approx(2.01) and small[0, 2] == 0.0 and small[1, 3] == 0.0
    assert cam.cx == pytest.approx(1.5) and cam.fx == pytest.approx(4.0)


def test_decimate_matches_the_slow_reference():
    rng = np.random.default_rng(6)
    depth = rng.uniform(1.97, 2.03, (24, 32)).astype(np.float32)
    depth[rng.random((24, 32)) < 0.3] = 0.0
    depth[:, 20:] += 3.0 * (rng.random((24, 12)) < 0.1)
    fast, _ = decimate(depth, CameraModel(32, 24, 30.0, 30.0, 15.5, 11.5), 4)
    slow = np.zeros((6, 8), np.float32)
    for r in range(6):
        for c in range(8):
            block = depth[4 * r:4 * r + 4, 4 * c:4 * c + 4]
            z = block[block > 0]
            if z.size >= 8 and z.max() - z.min() <= 0.05 * z.mean():
                slow[r, c] = z.mean()
    np.testing.assert_allclose(fast, slow, rtol=1e-6)
    assert 0 < (fast > 0).sum() < 48


def test_associate_pairs_nearest_once_within_tolerance():
    frames = np.array([0.0, 0.033, 0.066, 0.1, 0.5])
    depth = np.array([0.004, 0.030, 0.040, 0.098, 0.47])
    # 0.033 takes 0.030 (3 ms); 0.066 has nothing within 20 ms (0.040 is 26 ms off);
    # 0.5 has nothing (30 ms)
    np.testing.assert_array_equal(associate(frames, depth), [0, 1, -1, 3, -1])
    np.testing.assert_array_equal(associate(np.array([0.0, 0.01]), np.array([0.008])), [-1, 0])


def test_tum_fr1_rpy_depth_is_read_and_associated(data_dir):
    seq = open_sequence(data_dir / "tum_fr1_rpy")
    assert seq.has_depth
    with_depth = [i for i in (0, 1, 120, 239, 240, 500) if seq.depth(i) is not None]
    assert with_depth == [0, 1, 120, 239]
    depth = seq.depth(120)
    assert depth.dtype == np.float32 and depth.shape == (480, 640)
    assert 0.4 < np.median(depth[depth > 0]) < 4.0 and (depth > 0).mean() > 0.5
    raw = cv2.imread(str(data_dir / "tum_fr1_rpy" / "depth" / "1305031229.528784.png"),
                     cv2.IMREAD_UNCHANGED)
    np.testing.assert_allclose(seq.depth(0), raw / 5000.0, rtol=1e-6)


def test_tum_distributed_layout_reads_depth_txt(tmp_path):
    """rgb.txt and depth.txt of TUM RGB-D with their own (interleaved) clocks."""
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    rgb, dep = [], []
    for i in range(3):
        t = 10.0 + i / 30
        cv2.imwrite(str(tmp_path / f"rgb/{i}.png"), np.full((30, 40), 100 + i, np.uint8))
        cv2.imwrite(str(tmp_path / f"depth/{i}.png"), np.full((30, 40), 5000 * (i + 1),
                                                               np.uint16))
        rgb.append(f"{t:.6f} rgb/{i}.png")
        dep.append(f"{t + 0.004:.6f} depth/{i}.png")
    (tmp_path / "rgb.txt").write_text("# color images\n" + "\n".join(rgb) + "\n")
    (tmp_path / "depth.txt").write_text("# depth maps\n" + "\n".join(dep) + "\n")
    save_camera(SMALL, tmp_path / "camera.yaml")
    seq = open_sequence(tmp_path)
    assert [float(seq.depth(i)[0, 0]) for i in range(3)] == pytest.approx([1.0, 2.0, 3.0])
    assert float(seq.depth_at(seq.timestamps[1])[5, 5]) == pytest.approx(2.0)


def test_depth_txt_on_another_clock_is_a_clear_error(tmp_path):
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images/0.png"), np.zeros((30, 40), np.uint8))
    (tmp_path / "frames.txt").write_text("1.0 images/0.png\n")
    (tmp_path / "depth.txt").write_text("5000.0 depth/0.png\n")
    save_camera(SMALL, tmp_path / "camera.yaml")
    with pytest.raises(InputError, match="same clock"):
        open_sequence(tmp_path)


def test_rendered_depth_loads_back_as_rendered(tmp_path):
    out = tmp_path / "room"
    assert main(["render", "room-handheld", "--out", str(out), "--frames", "2", "--size",
                 "96x72", "--textures", "procedural", "--depth"]) == 0
    spec = load_depth_spec(out / "camera.yaml")
    assert spec.scale == 0.001 and spec.registered and spec.max_m == 10.0
    seq = open_sequence(out)
    memory = synthetic_sequence("room-handheld", 2, (96, 72), textures="procedural")
    np.testing.assert_allclose(seq.depth(1), memory.depth(1), atol=0.0006)
    assert (seq.depth(1) > 0).mean() > 0.8


def test_depth_sensor_needs_depth(tmp_path, capsys):
    assert main(["render", "hover-down", "--out", str(tmp_path / "x"), "--frames", "1",
                 "--depth-sensor", "ideal"]) == 2
    assert "--depth" in capsys.readouterr().err


def test_a_plain_image_folder_reads_its_depth_txt(tmp_path):
    """Images without a frame list are timed at fps from 0; a depth.txt on that clock
    gives them depth, as in the shared layout."""
    (tmp_path / "depth").mkdir()
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"{i}.png"), np.full((30, 40), 50, np.uint8))
        cv2.imwrite(str(tmp_path / f"depth/{i}.png"), np.full((30, 40), 1000 * (i + 1),
                                                               np.uint16))
    (tmp_path / "depth.txt").write_text("".join(f"{i / 10:.3f} depth/{i}.png\n"
                                                for i in range(3)))
    save_camera(SMALL, tmp_path / "camera.yaml", depth=DepthSpec(0.001))
    seq = open_sequence(tmp_path, fps=10.0)
    assert seq.has_depth
    assert [float(seq.depth(i)[3, 4]) for i in range(3)] == pytest.approx([1.0, 2.0, 3.0])
