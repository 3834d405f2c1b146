"""`sdvl track-compare`: argument errors, the per-stage comparison of two trackers' reports and
the difference of their trajectories (the timed runs themselves take minutes: not here)."""

from __future__ import annotations

import pytest

from sdvl.cli import main
from sim.track_compare_command import (
    Side,
    compare,
    format_summary,
    parse_spec,
    trajectory_difference,
)


def _report(track: float, align: float, p95: float, tracked: int = 100) -> dict:
    return {"stages": {"track": track, "align": align},
            "stages_p95": {"track": p95, "align": 2 * align},
            "tracked": tracked, "segments": 1, "ate_rmse_m": 0.01}


def test_compare_takes_the_median_of_the_rounds_and_their_ratios(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n")
    b.write_text("1.0 0 0 0 0 0 0 1\n2.0 1.000000002 0 0 0 0 0 1\n")
    before = Side([_report(4.0, 1.0, 8.0), _report(5.0, 1.2, 9.0), _report(6.0, 1.1, 30.0)], a)
    after = Side([_report(2.0, 0.5, 4.0), _report(3.0, 0.6, 5.0), _report(3.3, 0.7, 6.0)], b)
    s = compare({"before": before, "after": after})
    track = s["stages"]["track"]
    assert (track["before"], track["before_p95"], track["after"], track["after_p95"]) == (
        5.0, 9.0, 3.0, 5.0)
    assert track["ratio"] == pytest.approx(0.55)  # rounds: 0.5, 0.6, 0.55
    assert s["pose_difference"] == pytest.approx(2e-9)
    text = format_summary("abc123", 3, {"seq": s})
    assert "abc123" in text and "0.550" in text and "p95/median  before 1.80, after 1.67" in text
    assert "tracked 100 -> 100" in text


def test_trajectories_of_different_lengths_differ_without_bound(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("1.0 0 0 0 0 0 0 1\n")
    b.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n")
    assert trajectory_difference(a, b) == float("inf")
    assert trajectory_difference(a, None) is None


def test_specs_and_argument_errors(capsys):
    assert parse_spec("kitti00_first200@vo/presets/kitti_10hz.toml") == (
        "kitti00_first200", "vo/presets/kitti_10hz.toml")
    assert parse_spec("tum_fr1_rpy") == ("tum_fr1_rpy", None)
    assert main(["track-compare", "--against", "no-such-revision-xyz", "tum_fr1_rpy"]) == 2
    assert "not a revision" in capsys.readouterr().err
    assert main(["track-compare", "--against", "HEAD", "--rounds", "0", "tum_fr1_rpy"]) == 2
