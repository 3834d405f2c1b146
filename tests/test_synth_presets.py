"""Every preset renders through `sdvl render` and loads back through the dataset reader; the
in-memory sequences are deterministic and carry their events."""

from __future__ import annotations

import numpy as np
import pytest

from sdvl.cli import main
from sim.datasets import open_sequence
from sim.synth.flight import synthetic_sequence
from sim.synth.presets import PRESETS

SIZE = (96, 72)


@pytest.mark.parametrize("preset", list(PRESETS))
def test_rendered_preset_loads_through_open_sequence(preset, tmp_path):
    out = tmp_path / preset
    argv = ["render", preset, "--out", str(out), "--frames", "3", "--size", "96x72",
            "--seed", "2", "--textures", "procedural"]
    assert main(argv) == 0
    seq = open_sequence(out)
    frames = list(seq.frames())
    assert len(frames) == 3 and frames[0][1].shape == (72, 96)
    memory = synthetic_sequence(preset, 3, SIZE, seed=2, textures="procedural")
    np.testing.assert_array_equal(frames[2][1], memory.image(2))
    np.testing.assert_allclose(seq.groundtruth.positions, memory.groundtruth.positions,
                               atol=1e-8)
    np.testing.assert_allclose(seq.imu.accel, memory.imu.accel, atol=1e-8)
    sensors = seq.extras["sensors"]
    np.testing.assert_allclose(sensors.baro_alt, memory.extras["sensors"].baro_alt, atol=1e-8)
    assert sensors.range_valid.all() and frames[0][1].std() > 10
    assert seq.extras["world"] == "NED"
    np.testing.assert_allclose(seq.extras["T_b_c"], memory.extras["T_b_c"])


def test_preset_name_opens_in_memory():
    seq = open_sequence("hover-down")
    assert seq.camera.size == (640, 480) and seq.extras["world"] == "NED"
    assert 19.0 < seq.timestamps[-1] < 21.0


def test_seed_makes_flights_repeatable_and_different():
    a, b = (synthetic_sequence("walkers", 2, SIZE, seed=s, textures="procedural")
            for s in (1, 1))
    c = synthetic_sequence("walkers", 2, SIZE, seed=5, textures="procedural")
    np.testing.assert_array_equal(a.image(1), b.image(1))
    assert np.abs(a.image(1).astype(int) - c.image(1)).mean() > 5


def test_blackout_covers_the_lens_and_kidnap_skips_frames():
    seq = synthetic_sequence("blackout", size=SIZE, textures="procedural")
    (start, end), = seq.extras["blackouts"]
    inside = np.flatnonzero((seq.timestamps >= start) & (seq.timestamps < end))
    assert inside.size == 90 and seq.image(int(inside[5])).mean() < 10
    assert seq.image(int(inside[-1]) + 1).mean() > 50
    jump = synthetic_sequence("kidnap", size=SIZE, textures="procedural")
    assert np.diff(jump.timestamps).max() == pytest.approx(4.0, abs=0.04)
    assert jump.imu.t[-1] == pytest.approx(jump.timestamps[-1])


def test_walkers_stand_under_the_stop_then_walk_off():
    seq = synthetic_sequence("walkers", size=SIZE, textures="procedural")
    empty = synthetic_sequence("walkers-empty", size=SIZE, textures="procedural")
    np.testing.assert_array_equal(seq.groundtruth.positions, empty.groundtruth.positions)
    movers = seq.image_loader.spec.scene.movers
    group = [m for m in movers if m.t_start == 0.0]
    assert len(movers) == 20 and len(group) == 14
    leave = min(m.pause for m in group)
    i = int(np.searchsorted(seq.timestamps, leave - 0.5))  # the drone holds above the group
    assert np.linalg.norm(seq.groundtruth.positions[i, :2]) < 0.5
    assert np.abs(seq.image(i).astype(int) - empty.image(i)).max() > 50
    start = np.array([m.quads(0.0).geometry[0, :2] for m in group])
    later = np.array([m.quads(leave + 3.0).geometry[0, :2] for m in group])
    assert np.all(np.linalg.norm(later - start, axis=1) > 1.0)  # the whole group walked off


def test_bad_render_arguments_are_one_line_errors(tmp_path, capsys):
    assert main(["render", "nope", "--out", str(tmp_path)]) == 2
    assert main(["render", "hover-down", "--out", str(tmp_path), "--size", "big"]) == 2
    assert main(["render", "hover-down", "--out", str(tmp_path), "--frames", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("sdvl render: error:") for line in err)
