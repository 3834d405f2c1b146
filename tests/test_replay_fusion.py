"""The replay with the fusion EKF: a known flight in NED, a tracker that reports the ground
truth in its own scaled and rotated world, the simulated autopilot streaming the flight's
sensors. The received poses are scored after only the start alignment, and `sdvl eval --align
none` on the written files agrees."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from daemon.config import Config, replace
from daemon.mounting import body_from_camera
from sim.cli import main
from sim.replay.harness import run_replay
from sim.replay.report import build_report
from sim.sequence import Sequence
from sim.trajectory import Trajectory
from vo.result import FrameResult

FPS = 30.0
VO_SCALE = 0.5  # tracker units per metre


def take_off_and_drift(duration_s: float) -> Trajectory:
    """Downward camera on a vehicle that climbs 0.5 -> 2.5 m in 3 s, then drifts and turns."""
    t = np.arange(0.0, duration_s, 1.0 / FPS)
    c = np.clip(t / 3.0, 0.0, 1.0)
    z = -(0.5 + 2.0 * (3 * c**2 - 2 * c**3))
    x = np.where(t > 4, 1.5 * np.sin(0.4 * (t - 4)), 0.0)
    y = np.where(t > 4, 1.0 - np.cos(0.3 * (t - 4)), 0.0)
    euler = np.column_stack([0.3 + 0.05 * t, 0.03 * np.sin(t), 0.02 * np.cos(t)])
    R_ned_c = Rotation.from_euler("ZYX", euler) * Rotation.from_matrix(
        body_from_camera(Config().mounting))
    return Trajectory(t, np.column_stack([x, y, z]), R_ned_c.as_quat())


class GroundTruthTracker:
    """Reports the camera's true pose in a tracker world rotated, shifted and scaled from NED."""

    def __init__(self, groundtruth: Trajectory):
        self.gt = groundtruth
        self.T_vo_ned = np.eye(4)
        self.T_vo_ned[:3, :3] = Rotation.from_euler("xyz", [0.4, -0.2, 1.0]).as_matrix()
        self.T_vo_ned[:3, 3] = [1.0, 2.0, 3.0]

    def process(self, image: np.ndarray, t: float) -> FrameResult:
        i = int(np.argmin(np.abs(self.gt.t - t)))
        T = self.T_vo_ned @ self.gt.matrices()[i]
        T[:3, 3] *= VO_SCALE
        return FrameResult(t, T, "good", np.diag([1e-6] * 6), 100, 120, 90, {}, i == 0)

    def close(self) -> None:
        """Nothing to release."""


def test_fusion_replay_scores_ned_positions_after_the_start_alignment(tmp_path, capsys):
    gt = take_off_and_drift(10.0)
    image = np.zeros((24, 32), np.uint8)
    sequence = Sequence("take-off", CameraModel(32, 24, 20.0, 20.0, 16.0, 12.0, "none", []),
                        gt.t, image_loader=lambda i: image, groundtruth=gt,
                        extras={"T_ned_world": np.eye(4)})
    config = replace(Config(), fusion={"enabled": True})
    run = run_replay(sequence, config, realtime=True, progress=False,
                     make_tracker=lambda frame: GroundTruthTracker(gt))
    r, aligned, reference = build_report(run, tmp_path)
    assert r["estimator"] == "fusion" and r["align"] == "start" and r["scale"] == 1.0
    assert r["resets"] == 0
    assert r["dropped"] <= 0.05 * len(gt)  # realtime: a loaded test machine may drop a few
    assert r["tracked"] == r["processed"]
    assert r["messages_received"] >= 150  # published once scale and heading converged
    assert r["ate_rmse_m"] < 0.05 and r["rot_rmse_deg"] < 1.0
    assert r["velocity_rmse_m_s"] < 0.1
    assert aligned is not None
    from sim.plots import plot_replay

    plot_replay(aligned, reference, tmp_path / "fusion.png", "fusion replay", ned=True)
    assert (tmp_path / "fusion.png").stat().st_size > 20_000

    assert main(["eval", r["groundtruth_file"], r["received_file"], "--align", "none",
                 "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["ate_rmse_m"] == pytest.approx(r["ate_rmse_m"], rel=1e-6)
