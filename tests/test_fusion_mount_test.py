"""The mount self-test reads hand motion as forward/right/up with the right mounting, and
shows a wrong mounting as the wrong words."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from daemon.config import MountingConfig
from daemon.mount_test import MountTest
from daemon.mounting import body_from_camera
from sdvl.cli import main
from vo.result import FrameResult

MOVES = {"FORWARD": [1.0, 0.0, 0.0], "RIGHT": [0.0, 1.0, 0.0], "UP": [0.0, 0.0, -1.0]}


def readings(actual: MountingConfig, configured: MountingConfig, move: list) -> list:
    """Tracker results for a vehicle carried 0.5 m along `move` (body FRD), seen by a camera
    mounted as `actual`, read with the `configured` mounting."""
    rng = np.random.default_rng(0)
    R_w_n = Rotation.random(random_state=1).as_matrix()  # the tracker's arbitrary world
    R_n_b = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    R_b_c = body_from_camera(actual)
    test, out = MountTest(configured, min_move=0.05), []
    for k, s in enumerate(np.linspace(0.0, 0.5, 20)):
        T = np.eye(4)
        T[:3, :3] = R_w_n @ R_n_b @ R_b_c
        T[:3, 3] = 0.3 * (R_w_n @ R_n_b @ (s * np.array(move))) + rng.normal(0, 1e-3, 3)
        reading = test.on_result(FrameResult(0.1 * k, T, "good", new_segment=k == 0))
        if reading is not None:
            out.append(reading)
    return out


@pytest.mark.parametrize("preset", ["down", "forward"])
@pytest.mark.parametrize("expected", list(MOVES))
def test_right_mounting_reads_the_motion(preset: str, expected: str) -> None:
    mounting = MountingConfig(preset=preset)
    out = readings(mounting, mounting, MOVES[expected])
    assert out and all(r.direction == expected for r in out)
    assert expected in out[-1].line()
    assert abs(out[-1].yaw_deg) < 1.0


def test_wrong_mounting_shows_up() -> None:
    out = readings(MountingConfig(preset="down"), MountingConfig(preset="forward"),
                   MOVES["FORWARD"])
    assert out and out[-1].direction != "FORWARD"


def test_custom_yaw_mounting() -> None:
    mounting = MountingConfig(preset="custom", pitch_deg=-90.0, yaw_deg=90.0)
    assert readings(mounting, mounting, MOVES["RIGHT"])[-1].direction == "RIGHT"


def test_command_reports_a_bad_config_in_one_line(tmp_path, capsys) -> None:
    config = tmp_path / "sdvl.toml"
    config.write_text("[mounting]\npreset = \"sideways\"\n")
    assert main(["mount-test", "--config", str(config)]) == 2
    assert "mounting.preset" in capsys.readouterr().err
