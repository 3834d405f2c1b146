"""`sdvl replay` end to end: real sequences through the whole service and the simulated
autopilot, with pass thresholds; the JSON keys; the ATE agrees with `sdvl eval`."""

from __future__ import annotations

import json

import pytest

from sdvl.cli import main

REQUIRED = ("frames", "processed", "dropped", "tracked", "ate_rmse_m", "latency_ms_p99",
            "messages_received", "resets")


def replay_json(capsys, *args: str) -> dict:
    assert main(["replay", *args, "--json", "--quiet"]) == 0
    return json.loads(capsys.readouterr().out)


def test_vamr_fast_replay_scores_json_plot_and_agrees_with_eval(data_dir, tmp_path, capsys):
    png = tmp_path / "replay.png"
    r = replay_json(capsys, str(data_dir / "vamr_ex01_checkerboard736"), "--fast",
                    "--max-frames", "300", "--out", str(tmp_path), "--plot", str(png))
    assert set(REQUIRED) <= set(r)
    assert r["mode"] == "fast" and r["estimator"] == "pass-through" and r["align"] == "sim3"
    assert r["frames"] == 300 and r["processed"] == 300 and r["dropped"] == 0
    assert r["tracked_fraction"] >= 0.85 and r["resets"] == 0
    # every tracked frame but the first of the map reaches the autopilot (rate-limited replay),
    # or was too old to send when the machine is busy
    assert r["messages_received"] + r["skipped_stale"] >= r["tracked"] - 5
    assert r["scored"] == r["messages_received"]
    assert r["ate_rmse_m"] < 0.005  # path ~1 m over the checkerboard; C++ SDVL: 0.0047 m full
    assert r["velocity_rmse_m_s"] is not None and r["latency_ms_p99"] > 0
    assert png.stat().st_size > 20_000

    assert main(["eval", r["groundtruth_file"], r["received_file"], "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["matched"] == r["scored"]
    assert ev["ate_rmse_m"] == pytest.approx(r["ate_rmse_m"], rel=1e-6)
    assert ev["rot_rmse_deg"] == pytest.approx(r["rot_rmse_deg"], rel=1e-6)


def test_tum_replay(data_dir, tmp_path, capsys):
    # --fast with mapping inline: every frame is tracked and mapped, so the score does not
    # depend on the machine's load
    config = tmp_path / "inline.toml"
    config.write_text("[service]\nmapping_thread = false\n")
    r = replay_json(capsys, str(data_dir / "tum_fr1_rpy"), "--fast", "--max-frames", "300",
                    "--config", str(config), "--out", str(tmp_path))
    assert r["mode"] == "fast" and r["frames"] == r["processed"] == 300
    # the fast roll (frames 34-67 and 154-188) can lose the map: a new one is a reset
    assert r["tracked"] >= 0.65 * r["frames"] and r["resets"] <= 4
    assert r["messages_received"] + r["skipped_stale"] >= r["tracked"] - 5  # stale: busy
    # mostly rotation (~0.2 m of translation, a constant estimate scores ~0.05 m): the
    # rotation is the score, the position only caught running off
    assert r["rot_rmse_deg"] < 15.0 and r["ate_rmse_m"] < 0.05
    # at most one message a frame; how fast they come and how late is the machine's business
    assert r["messages_received"] <= r["processed"] and r["latency_ms_p99"] > 0


def test_tum_realtime_replay_paces_and_counts_drops(data_dir, tmp_path, capsys):
    r = replay_json(capsys, str(data_dir / "tum_fr1_rpy"), "--realtime", "--max-frames", "120",
                    "--out", str(tmp_path))
    assert r["mode"] == "realtime" and r["frames"] == 120
    assert r["processed"] + r["dropped"] == r["frames"]
    # ~10 ms tracking per 33 ms frame drops nothing on an idle 2-core machine (sdvl replay
    # --realtime measures it); how many a loaded machine drops follows its load (0.52 beside
    # the suite and two trackers), so only that the newest frame keeps being taken is tested
    assert r["processed"] >= 1 and r["drop_fraction"] < 1.0
    assert r["messages_received"] <= r["processed"]  # never more than one message a frame


def test_text_report_and_bad_input(data_dir, tmp_path, capsys):
    seq = str(data_dir / "vamr_ex01_checkerboard736")
    assert main(["replay", seq, "--max-frames", "40", "--quiet", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "ATE RMSE" in text and "capture-to-send" in text and "40 offered" in text
    assert main(["replay", seq, "--max-frames", "0"]) == 2
    assert "--max-frames" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "missing")]) == 2


def test_synthetic_take_off_replay_with_pass_through(tmp_path, capsys):
    # rendered on the fly (fast mode); --estimator pass-through scores the tracker's map
    r = replay_json(capsys, "hover-down", "--fast", "--estimator", "pass-through",
                    "--max-frames", "150", "--out", str(tmp_path))
    assert r["sequence"] == "hover-down" and r["estimator"] == "pass-through"
    assert r["frames"] == 150 and r["dropped"] == 0
    assert r["tracked_fraction"] >= 0.75 and r["resets"] == 0
    assert r["messages_received"] + r["skipped_stale"] >= 0.9 * r["tracked"]  # stale: busy
    assert r["ate_rmse_m"] < 0.4  # a 2.5 m climb with a slow wander; measured 0.15 m


@pytest.mark.parametrize(("preset", "max_ate_m"), [("survey-down", 0.03), ("room-handheld", 0.02)])
def test_synthetic_preset_replays(tmp_path, capsys, preset, max_ate_m):
    # measured with mapping inline: 0.0055 m (survey-down), 0.0035 m (room-handheld)
    config = tmp_path / "inline.toml"
    config.write_text("[service]\nmapping_thread = false\n")
    r = replay_json(capsys, preset, "--fast", "--estimator", "pass-through", "--max-frames",
                    "150", "--config", str(config), "--out", str(tmp_path))
    assert r["frames"] == 150 and r["dropped"] == 0 and r["resets"] == 0
    assert r["tracked_fraction"] >= 0.8
    assert r["messages_received"] + r["skipped_stale"] >= r["tracked"] - 5  # stale: busy
    assert r["ate_rmse_m"] < max_ate_m
