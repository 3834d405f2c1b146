"""`sdvl track-table`: rows per sequence and configuration, the original figures, bad names."""

from __future__ import annotations

import json

from sim.cli import main


def test_table_rows_and_original_figures(data_dir, capsys, monkeypatch):
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "patch,patch+rej",
                 "--max-frames", "40"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["sequence", "config", "tracked"]
    assert [line.split()[1] for line in lines[1:3]] == ["patch", "patch+rej"]
    assert "original C++" in lines[3] and "0.0047" in lines[3]
    assert main(["track-table", "vamr_ex01_checkerboard736", "--configs", "patch+ba",
                 "--max-frames", "40", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["config"] == "patch+ba" and row["frames"] == 40 and row["tracked"] >= 25
    assert row["ate_rmse_m"] < 0.01


def test_unknown_configuration_is_one_line_error(capsys):
    assert main(["track-table", "x", "--configs", "patch,orb"]) == 2
    err = capsys.readouterr().err.strip()
    assert "orb" in err and "\n" not in err
