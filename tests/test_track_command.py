"""`sdvl track`: report fields, trajectory file, per-frame CSV, config errors."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sdvl.cli import main
from sim.track_command import FRAME_COLUMNS, format_report
from sim.track_relocs import relocalisation_errors
from sim.trajectory import Trajectory, read_tum


def test_track_json_and_trajectory(data_dir, tmp_path, capsys):
    out = tmp_path / "traj.txt"
    code = main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--max-frames", "60",
                 "--json", "--quiet", "--out", str(out)])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("frames", "tracked", "ate_rmse_m", "track_ms_median", "track_ms_p95", "stages"):
        assert key in report
    assert report["frames"] == 60 and report["tracked"] >= 45
    assert report["ate_rmse_m"] is not None and report["ate_rmse_m"] < 0.01
    assert {"track", "align", "reproject", "pose"} <= set(report["stages"])
    assert len(read_tum(out)) == report["tracked"]


def test_track_text_report_by_name_with_config(data_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SDVL_DATA", str(data_dir))
    cfg = tmp_path / "c.toml"
    cfg.write_text("[tracker]\nmax_matches = 120\n")
    assert main(["track", "vamr_ex01_checkerboard736", "--max-frames", "30", "--quiet",
                 "--config", str(cfg)]) == 0
    text = capsys.readouterr().out
    assert "ATE RMSE" in text and "track" in text


def test_bad_config_is_one_line_error(tmp_path, capsys, data_dir):
    cfg = tmp_path / "c.toml"
    cfg.write_text("max_matchez = 3\n")
    code = main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--config", str(cfg)])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "max_matchez" in err and len(err.splitlines()) == 1
    assert main(["track", str(tmp_path / "nowhere")]) == 2


def test_memory_samples_on_a_small_synthetic_flight(capsys):
    assert main(["track", "survey-long", "--size", "160x120", "--max-frames", "40",
                 "--memory", "20", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [m["frame"] for m in report["memory"]] == [20, 40]
    assert report["peak_rss_mb"] >= report["memory"][-1]["rss_mb"] > 10
    assert all(m["keyframes"] >= 0 and m["points"] >= 0 for m in report["memory"])
    text = format_report(report)
    assert "peak RSS" in text and "keyframes" in text


def test_size_is_only_for_synthetic_presets(data_dir, capsys):
    code = main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--size", "160x120"])
    assert code == 2
    assert "--size is for synthetic presets" in capsys.readouterr().err


def test_frames_csv_has_a_row_per_frame_and_the_ate_errors(data_dir, tmp_path, capsys):
    path = tmp_path / "frames.csv"
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--max-frames", "60",
                 "--json", "--quiet", "--frames-csv", str(path),
                 "--config", str(_rejection_config(tmp_path))]) == 0
    report = json.loads(capsys.readouterr().out)
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 60 and tuple(rows[0]) == FRAME_COLUMNS
    errors = np.array([float(r["error_m"]) for r in rows if r["error_m"]])
    assert len(errors) == report["tracked"]
    # the per-frame errors (written to the micrometre) are the ones the ATE is the RMS of
    assert np.sqrt(np.mean(errors ** 2)) == pytest.approx(report["ate_rmse_m"], abs=1e-6)
    tracked = [r for r in rows if r["quality"] in ("good", "insufficient")]
    assert all(int(r["inliers"]) <= int(r["matches"]) <= int(r["attempts"]) for r in tracked)
    assert any(int(r["ransac_hypotheses"]) > 0 for r in tracked)
    assert sum(int(r["new_segment"]) for r in rows) >= 1
    # the initialiser's frames had no pose live; posed late, they have an error too
    waited = [r for r in rows if r["quality"] == "initializing"]
    assert sum(r["error_m"] != "" for r in waited) == report["tracked_late"] == len(waited)
    assert sum(int(r["keyframe"]) for r in rows) >= 2


def _rejection_config(tmp_path):
    cfg = tmp_path / "rejection.toml"
    cfg.write_text("outlier_rejection = true\n")
    return cfg


def test_emulated_slow_mapping_skips_frames(data_dir, capsys):
    """--mapping-period 3: mapping at a third of the frame rate, so whole frames are skipped
    (about two in three once the backlog is full); the same run twice is the same."""
    args = ["track", str(data_dir / "vamr_ex01_checkerboard736"), "--max-frames", "60",
            "--json", "--quiet", "--mapping-period", "3"]
    reports = []
    for _ in range(2):
        assert main(args) == 0
        reports.append(json.loads(capsys.readouterr().out))
    report = reports[0]
    assert report["frames"] == 60 and 25 <= report["skipped"] <= 40
    assert report["tracked"] <= 60 - report["skipped"]
    assert report["ate_rmse_m"] == reports[1]["ate_rmse_m"]
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--threaded",
                 "--mapping-period", "2"]) == 2
    assert "--mapping-period" in capsys.readouterr().err


def test_relocalisation_errors_measure_the_jump_and_the_added_error():
    # a camera turning about z at 1 degree per pose; the estimate is the truth in another
    # world frame at another scale, except pose 30, relocalised 10 degrees off about x
    n = 40
    t = np.arange(n) / 10.0
    rot = Rotation.from_euler("z", np.arange(n)[:, None], degrees=True)
    truth = Trajectory(t, np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n)]),
                       rot.as_quat())
    frame = Rotation.from_euler("y", 30, degrees=True)
    off = np.array([frame] * n, dtype=object)
    off[30] = frame * Rotation.from_euler("x", 10, degrees=True)
    est_rot = Rotation.concatenate([off[k] * rot[k] for k in range(n)])
    est = Trajectory(t, 2.0 * truth.positions @ frame.as_matrix().T, est_rot.as_quat())
    segment = np.zeros(n, dtype=int)
    (e,) = relocalisation_errors(truth, est, segment, np.array([30]))
    assert abs(e["jump_rot_err_deg"] - 10.0) < 1e-6 and e["jump_pos_err_m"] < 1e-9
    assert abs(e["rot_err_deg"] - 10.0) < 1e-6 and e["rot_err_before_deg"] < 1e-6
    assert relocalisation_errors(truth, est, segment, np.array([1])) == []  # too few before


def test_profile_lists_the_tracker_functions_per_frame(data_dir, capsys):
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--max-frames", "30",
                 "--profile", "8", "--json", "--quiet"]) == 0
    profile = json.loads(capsys.readouterr().out)["profile"]
    assert profile["frames"] == 30 and profile["calls_per_frame"] > 100
    functions = profile["functions"]
    assert len(functions) == 8
    own = [f["own_ms"] for f in functions]
    assert own == sorted(own, reverse=True) and all(f["cum_ms"] >= f["own_ms"] for f in functions)
    assert any(f["function"].startswith("vo/") for f in functions)  # the tracker's own code
    slow = [f["stages"]["track"] for f in profile["slowest"]]
    assert len(slow) == 5 and slow == sorted(slow, reverse=True)
    assert all(f["quality"] != "initializing" for f in profile["slowest"])
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--profile", "5",
                 "--threaded"]) == 2  # cProfile sees one thread: a clear error


def test_every_kth_frame_keeps_times_images_and_ground_truth(data_dir, tmp_path, capsys):
    from sim.datasets import open_sequence
    from sim.sequence import Sequence, every

    seq = open_sequence(data_dir / "vamr_ex01_checkerboard736")
    third = every(seq, 3)
    assert len(third) == 246 and third.groundtruth is seq.groundtruth
    frames = list(third.frames(2))
    assert [t for t, _ in frames] == [seq.timestamps[0], seq.timestamps[3]]
    assert np.array_equal(frames[1][1], seq.image(3))
    # a stream read in order (video, synthetic presets) is thinned the same way
    stream = Sequence("s", seq.camera, seq.timestamps[:7],
                      frame_iter=lambda: ((float(i), np.full((2, 2), i, np.uint8))
                                          for i in range(7)))
    assert [t for t, _ in every(stream, 3).frames()] == [0.0, 3.0, 6.0]
    out = tmp_path / "t.txt"
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--every", "3",
                 "--max-frames", "40", "--json", "--quiet", "--out", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 40
    times = read_tum(out).t
    assert np.all(np.isin(times, seq.timestamps[:120:3]))
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--every", "0"]) == 2
    assert "--every must be at least 1" in capsys.readouterr().err
