"""The replay with the fusion EKF: a known flight in NED, a tracker that reports the ground
truth in its own scaled and rotated world, the simulated autopilot streaming the flight's
sensors. The received poses are scored after only the start alignment, and `sdvl eval --align
none` on the written files agrees. The lockstep replay (`--fast` with fusion) is deterministic,
uses the flight's recorded sensors and leaves sensors out on request; the fusion scores."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from daemon.config import Config, replace
from daemon.mounting import body_from_camera
from sdvl.cli import main
from sim.metrics import align_trajectories
from sim.replay.fusion_scores import fusion_scores, nees_per_dof, takeoff_time, velocity_at
from sim.replay.harness import run_replay
from sim.replay.lockstep import autopilot_messages
from sim.replay.report import build_report, format_report
from sim.sequence import Sequence
from sim.synth.flight import synthetic_sequence
from sim.trajectory import Trajectory
from vo.result import FrameResult

FPS = 30.0
LOCKSTEP_FRAMES = 150
VO_SCALE = 0.5  # tracker units per metre


def take_off_and_drift(duration_s: float) -> Trajectory:
    """Downward camera on a vehicle that climbs 0.5 -> 2.5 m in 3 s, then drifts and turns, as
    a vehicle can (an instant change of velocity would be an IMU spike, which the fusion
    rejects)."""
    t = np.arange(0.0, duration_s, 1.0 / FPS)
    c = np.clip(t / 3.0, 0.0, 1.0)
    z = -(0.5 + 2.0 * (3 * c**2 - 2 * c**3))
    x = np.where(t > 4, 1.5 * (1.0 - np.cos(0.4 * (t - 4))), 0.0)  # no step in velocity
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

    def process(self, image: np.ndarray, t: float, **extra) -> FrameResult:
        i = int(np.argmin(np.abs(self.gt.t - t)))
        T = self.T_vo_ned @ self.gt.matrices()[i]
        T[:3, 3] *= VO_SCALE
        return FrameResult(t, T, "good", covariance=np.diag([1e-6] * 6), n_matches=100,
                           n_attempts=120, n_inliers=90, new_segment=i == 0)

    def close(self) -> None:
        """Nothing to release."""


def _take_off_replay(realtime: bool, out_dir):
    """A take-off and drift replayed through the fusion with the ground truth as tracker: the
    report, the aligned trajectories and the reference."""
    gt = take_off_and_drift(10.0)
    image = np.zeros((24, 32), np.uint8)
    sequence = Sequence("take-off", CameraModel(32, 24, 20.0, 20.0, 16.0, 12.0, "none", []),
                        gt.t, image_loader=lambda i: image, groundtruth=gt,
                        extras={"T_ned_world": np.eye(4)})
    config = replace(Config(), fusion={"enabled": True})
    run = run_replay(sequence, config, realtime=realtime, progress=False,
                     make_tracker=lambda frame: GroundTruthTracker(gt))
    r, aligned, reference = build_report(run, out_dir)
    assert r["estimator"] == "fusion" and r["align"] == "start" and r["scale"] == 1.0
    assert r["resets"] == 0
    assert r["tracked"] == r["processed"]
    return r, aligned, reference, len(gt)


def test_realtime_fusion_replay_publishes_ned_poses(tmp_path):
    """The README's default: the autopilot in its own process, frames at the camera's rate."""
    r, _, _, _ = _take_off_replay(True, tmp_path)
    # how many frames a busy machine drops is timing (17 to 63 of 300 seen beside other work),
    # and the error with it (ATE 0.003-0.069 m; lockstep 0.013 m): only what no load changes is
    # asserted here, a frame or axis mistake (metres over the 10 m climb); accuracy: lockstep
    assert r["messages_received"] >= 30
    assert r["ate_rmse_m"] < 0.5 and r["rot_rmse_deg"] < 1.0


def test_fusion_replay_scores_ned_positions_after_the_start_alignment(tmp_path, capsys):
    r, aligned, reference, frames = _take_off_replay(False, tmp_path)
    assert r["dropped"] == 0
    # published once scale and heading converged
    assert r["messages_received"] >= frames // 2
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



@pytest.fixture(scope="module")
def take_off():
    """The first 5 s of hover-down (climb from 1.5 m), images left blank (the tracker reports
    the ground truth), so nothing is rendered."""
    sequence = synthetic_sequence("hover-down", frames=LOCKSTEP_FRAMES, size=(64, 48), seed=1)
    blank = np.zeros((48, 64), np.uint8)
    return dataclasses.replace(sequence, image_loader=lambda i: blank)


def replay(sequence, without=()):
    # the tracker is the ground truth: its position does not drift like a real one's
    config = replace(Config(), fusion={"enabled": True, "vo_covariance_factor": 1.0})
    run = run_replay(sequence, config, realtime=False, progress=False, without=without,
                     make_tracker=lambda frame: GroundTruthTracker(sequence.groundtruth))
    return build_report(run, None)[0]


def test_lockstep_is_deterministic_and_scores_the_take_off(take_off) -> None:
    first, second = replay(take_off), replay(take_off)
    print("\n" + format_report(first))
    assert first["mode"] == "lockstep" and first["without"] == []
    for key in ("messages_received", "ate_rmse_m", "nees_position", "first_publish_s"):
        assert first[key] == second[key]
    assert first["messages_received"] >= 60
    assert first["ate_rmse_m"] < 0.1 and first["heading_rms_deg"] < 2.0
    assert first["takeoff_s"] is not None and first["climb_m"] > 2.0
    assert first["aligned_after_takeoff_s"] <= 5.0 and first["publish_after_takeoff_s"] < 0
    assert first["latency_ms_p50"] is None and first["message_rate_hz"] is None
    assert np.isfinite(first["nees_position"]) and np.isfinite(first["nees_velocity"])


def test_sensors_left_out_are_not_streamed(take_off) -> None:
    flight = Trajectory(take_off.groundtruth.t, take_off.groundtruth.positions,
                        take_off.groundtruth.quaternions)
    streams = {"ATTITUDE": 20, "SCALED_PRESSURE": 10}
    kinds = {m.get_type() for _, m in autopilot_messages(take_off, flight, streams, 2.0)}
    assert kinds == {"ATTITUDE", "SCALED_PRESSURE", "HEARTBEAT", "EXTENDED_SYS_STATE"}
    report = replay(take_off, without=("imu", "baro"))
    assert report["without"] == ["imu", "baro"]


def test_nees_heading_and_take_off_scores() -> None:
    errors = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    covariances = np.array([np.eye(3), 4 * np.eye(3)])
    assert nees_per_dof(errors, covariances) == pytest.approx(1 / 3)
    assert nees_per_dof(errors, np.full((2, 3, 3), np.nan)) is None
    t = np.linspace(0.0, 4.0, 41)
    height = np.where(t < 1.0, 1.0, 1.0 + (t - 1.0))
    yaw = np.radians(5.0)
    truth = Trajectory(t, np.column_stack([t, 0 * t, -height]),
                       np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)))
    estimate = Trajectory(t, truth.positions + np.array([0.0, 0.3, 0.0]),
                          np.tile(Rotation.from_euler("z", yaw).as_quat(), (len(t), 1)))
    start, climb = takeoff_time(truth, 0.0)
    assert start == pytest.approx(1.1) and climb == pytest.approx(3.0)
    aligned = align_trajectories(truth, estimate, "none")
    scores = fusion_scores(aligned, truth, np.zeros((len(t), 3)),
                           np.tile(0.09 * np.eye(3), (len(t), 1, 1)),
                           np.tile(np.eye(3), (len(t), 1, 1)), 0.0)
    assert scores["heading_rms_deg"] == pytest.approx(5.0)
    assert scores["heading_frame_rms_deg"] == pytest.approx(5.0)  # no compass bias given
    assert scores["nees_position"] == pytest.approx(1 / 3)
    assert scores["ate_pct_distance"] == pytest.approx(100 * 0.3 / scores["distance_m"])


def test_nees_is_scored_in_the_autopilots_heading_frame() -> None:
    """A flight flown exactly in a frame turned by the compass bias: true-north errors (ATE,
    heading), none in the frame the poses and their covariance are in (NEES, heading)."""
    t = np.linspace(0.0, 10.0, 101)
    truth = Trajectory(t, np.column_stack([3.0 * t, t, -5.0 + 0 * t]),
                       np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)))
    turn = Rotation.from_euler("z", -2.0, degrees=True)
    estimate = Trajectory(t, turn.apply(truth.positions - truth.positions[0])
                          + truth.positions[0], np.tile(turn.as_quat(), (len(t), 1)))
    aligned = align_trajectories(truth, estimate, "none")
    true_velocity = velocity_at(truth, t)
    velocity_error = turn.apply(true_velocity) - true_velocity
    covariance = np.tile(1e-4 * np.eye(3), (len(t), 1, 1))
    scores = fusion_scores(aligned, truth, velocity_error, covariance, covariance, 0.0, -2.0)
    assert scores["heading_rms_deg"] == pytest.approx(2.0)
    assert scores["heading_frame_max_deg"] == pytest.approx(0.0, abs=1e-9)
    assert scores["ate_pct_distance"] > 1.0
    assert scores["nees_position"] == pytest.approx(0.0, abs=1e-6)
    assert scores["nees_velocity"] == pytest.approx(0.0, abs=1e-3)
    assert scores["compass_bias_deg"] == -2.0


def test_barometer_alone_gives_the_scale_on_the_take_off() -> None:
    """No IMU, no rangefinder: the map's height against the barometer over the climb
    (daemon/fusion/climb_scale.py); before it, nothing was ever published."""
    sequence = synthetic_sequence("hover-down", frames=450, size=(64, 48), seed=1)
    blank = np.zeros((48, 64), np.uint8)
    report = replay(dataclasses.replace(sequence, image_loader=lambda i: blank),
                    without=("imu", "rangefinder"))
    print("\n" + format_report(report))
    assert report["first_publish_s"] is not None and report["messages_received"] >= 60
    assert report["ate_pct_distance"] <= 3.0
    assert report["nees_position"] <= 2.0
