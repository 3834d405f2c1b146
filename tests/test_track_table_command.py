"""`sdvl track-table`: the eight thesis configurations, rows per sequence and configuration,
the original figures, a failed run in its row, bad names."""

from __future__ import annotations

import json

import pytest

import sim.track_command
from sim.cli import main
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
