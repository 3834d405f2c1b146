"""`sdvl track-table`: the eight thesis configurations, rows per sequence and configuration,
the original figures, a failed run in its row, bad names."""

from __future__ import annotations

import json

import pytest

import sim.track_command
from sdvl.cli import main
from sim.track_table_command import CONFIGS, THESIS_NAMES, config_names


def test_the_eight_thesis_configurations():
    assert list(THESIS_NAMES.values()) == [f"Config{i}" for i in range(1, 9)]
    # thesis table 7.1: Config1..4 patches, 5..8 ORB; BA on in 3, 4, 7, 8; rejection in evens
    for name, thesis in THESIS_NAMES.items():
        i = int(thesis[-1])
        assert CONFIGS[name] == {"matcher": "orb" if i >= 5 else "patch",
                                 "local_ba": i in (3, 4, 7, 8),
                                 "outlier_rejection": i % 2 == 0}
    assert config_names("all") == list(CONFIGS)
    assert config_names("Config8, patch,config1") == ["orb+ba+rej", "patch"]


def test_table_rows_and_original_figures(data_dir, capsys, monkeypatch):
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "patch,orb+rej",
                 "--max-frames", "40", "--warm-up", "0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["sequence", "config", "tracked"]
    assert [line.split()[1:3] for line in lines[1:3]] == [["patch", "(Config1)"],
                                                          ["orb+rej", "(Config6)"]]
    assert "original C++" in lines[3] and "0.0047" in lines[3]
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "orb+ba",
                 "--max-frames", "40", "--warm-up", "0", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["config"] == "orb+ba" and row["thesis"] == "Config7" and row["frames"] == 40
    assert row["tracked"] >= 25 and row["ate_rmse_m"] < 0.01
    assert row["mapping_ms_mean"] > 0


def test_a_failed_run_is_reported_and_the_table_goes_on(data_dir, capsys, monkeypatch):
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    real = sim.track_command.track_sequence

    def flaky(sequence, config, *args, **kwargs):
        if config.matcher == "orb":
            raise RuntimeError("boom")
        return real(sequence, config, *args, **kwargs)

    monkeypatch.setattr(sim.track_command, "track_sequence", flaky)
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "orb,patch",
                 "--max-frames", "20", "--warm-up", "0"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert "failed: RuntimeError: boom" in lines[1]
    assert lines[2].split()[1] == "patch" and "/20" in lines[2]


@pytest.mark.parametrize("configs", ["patch,sift", ","])
def test_unknown_configuration_is_one_line_error(capsys, configs):
    assert main(["track-table", "x", "--configs", configs]) == 2
    err = capsys.readouterr().err.strip()
    assert "configuration" in err and "\n" not in err


def test_repeat_prints_each_rounds_p95_ratio_and_the_median(data_dir, capsys, monkeypatch):
    """Fake runs with known p95s: BA's ratio to the first configuration is 1.2, 0.9, 1.1 in
    the three rounds (median 1.1); --paced reaches the tracker run, --seeds its config."""
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    p95 = iter([10.0, 12.0, 20.0, 18.0, 10.0, 11.0])
    calls = []

    def fake(sequence, config, threaded, max_frames, quiet, paced=False, slow_mapping=None):
        calls.append((config.local_ba, config.seed, threaded, paced))
        return {"frames": 20, "tracked": 20, "segments": 1, "ate_rmse_m": 0.01,
                "longest_segment_ate_rmse_m": 0.01, "track_ms_median": 1.0,
                "track_ms_p95": next(p95), "stages": {}, "stages_mean": {}}, None

    monkeypatch.setattr(sim.track_command, "track_sequence", fake)
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "patch+rej,Config4",
                 "--max-frames", "20", "--warm-up", "0", "--threaded", "--paced",
                 "--repeat", "3", "--seeds", "2"]) == 0
    assert calls == [(False, 2, True, True), (True, 2, True, True)] * 3
    lines = [line for line in capsys.readouterr().out.splitlines() if "p95 /" in line]
    ratios = [float(line.rsplit(" ", 1)[1]) for line in lines]
    assert [line.split(":")[0].split(None, 1)[1] for line in lines] == [
        "round 1", "round 2", "round 3", "median of 3"]
    assert ratios == pytest.approx([1.2, 0.9, 1.1, 1.1])
    assert all("patch+ba+rej" in line for line in lines)


def test_a_sweep_compares_the_variants_seed_by_seed(data_dir, capsys, monkeypatch):
    """--set with two values and --seeds 0-2: every run per value and seed, then a summary
    per variant (fake runs whose ATE is known: grid_cell 16 is better on seeds 0 and 2)."""
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    ate = {(32, 0): 0.02, (32, 1): 0.01, (32, 2): 0.04, (16, 0): 0.01, (16, 1): 0.03,
           (16, 2): 0.02}
    runs = []

    def fake(sequence, config, threaded, max_frames, quiet, paced=False, slow_mapping=None):
        runs.append((config.grid_cell, config.seed, config.outlier_rejection, slow_mapping))
        return {"frames": 20, "tracked": 19, "segments": 1,
                "ate_rmse_m": ate[(config.grid_cell, config.seed)],
                "longest_segment_ate_rmse_m": None, "track_ms_median": 1.0,
                "track_ms_p95": 2.0, "stages": {}, "stages_mean": {}}, None

    monkeypatch.setattr(sim.track_command, "track_sequence", fake)
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "patch+rej",
                 "--max-frames", "20", "--warm-up", "0", "--seeds", "0-2",
                 "--set", "grid_cell=32,16", "--mapping-period", "2"]) == 0
    assert runs == [(g, s, True, (2, 0)) for g in (32, 16) for s in range(3)]
    out = capsys.readouterr().out.splitlines()
    rows = [line for line in out if "(Config2)" in line]
    assert len(rows) == 6 and "seed 1 grid_cell=16" in rows[4]
    summary = [line for line in out if "ATE mean" in line]
    assert len(summary) == 2
    assert "grid_cell=32" in summary[0] and "0.0233 m over 3 (0.02/0.01/0.04)" in summary[0]
    assert "better than grid_cell=32 on 2 of 3" in summary[1]


@pytest.mark.parametrize(("option", "word"), [(["--set", "grid_cell"], "KEY=VALUE"),
                                              (["--world-seeds", "0"], "synthetic"),
                                              (["--seeds", "2-1"], "empty")])
def test_bad_sweep_options_are_one_line_errors(data_dir, capsys, monkeypatch, option, word):
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    assert main(["track-table", "vamr_ex01_checkerboard736", "--warm-up", "0", *option]) == 2
    err = capsys.readouterr().err.strip()
    assert word in err and "\n" not in err


def test_paced_needs_threaded(capsys):
    assert main(["track-table", "x", "--paced"]) == 2
    assert "--threaded" in capsys.readouterr().err


def test_camera_rate_waits_for_each_frames_time(monkeypatch):
    """The first frame at once; later ones when their time since the first has passed on the
    clock (a fake one here); none when tracking is behind."""
    clock, sleeps = [100.0], []
    monkeypatch.setattr(sim.track_command.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(sim.track_command.time, "sleep", sleeps.append)
    pace = sim.track_command.camera_rate()
    pace(5.0)
    clock[0] += 0.01
    pace(5.1)  # 0.1 s after the first frame, 0.01 s later on the clock: waits 0.09 s
    clock[0] += 0.3
    pace(5.2)  # behind by 0.11 s: no wait
    assert sleeps == pytest.approx([0.09])
