"""Trajectory metrics: agreement with evo, alignment, interpolation, RPE, the eval command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.main_ape import ape as evo_ape
from evo.tools import file_interface
from scipy.spatial.transform import Rotation

from conftest import REAL_SEQUENCES
from sdvl.cli import main
from sim.metrics import evaluate, interpolate, umeyama
from sim.trajectory import Trajectory, read_tum, write_tum


def perturbed(gt: Trajectory, seed: int) -> Trajectory:
    """A copy of `gt` in another frame, scale, with noise and drift, at the same times."""
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(rng.normal(0, 1, 3))
    scale = rng.uniform(0.2, 5.0)
    noise = rng.normal(0, 0.01, (len(gt), 3)) + np.cumsum(rng.normal(0, 0.002, (len(gt), 3)), 0)
    rot_noise = Rotation.from_rotvec(rng.normal(0, 0.01, (len(gt), 3)))
    return Trajectory(gt.t, scale * R.apply(gt.positions + noise) + rng.normal(0, 3, 3),
                      (R * gt.rotations * rot_noise).as_quat())


@pytest.mark.parametrize("name", REAL_SEQUENCES)
@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_ate_agrees_with_evo_ape(data_dir, tmp_path, name, align):
    gt_path = data_dir / name / "groundtruth.txt"
    estimate = perturbed(read_tum(gt_path), seed=len(name))
    est_path = tmp_path / "estimate.txt"
    write_tum(estimate, est_path)
    ours = evaluate(read_tum(gt_path), read_tum(est_path), align)
    reference = evo_ape(file_interface.read_tum_trajectory_file(str(gt_path)),
                        file_interface.read_tum_trajectory_file(str(est_path)),
                        evo_metrics.PoseRelation.translation_part, align=True,
                        correct_scale=align == "sim3")
    assert ours.matched == len(estimate)
    assert abs(ours.ate_rmse_m - reference.stats["rmse"]) < 1e-6
    assert abs(ours.ate_max_m - reference.stats["max"]) < 1e-6
    assert abs(ours.ate_median_m - reference.stats["median"]) < 1e-6


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    R = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    dst = 2.5 * src @ R.T + [1, -2, 3]
    R_est, t_est, s_est = umeyama(src, dst, with_scale=True)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t_est, [1, -2, 3], atol=1e-12)
    assert s_est == pytest.approx(2.5)


def test_interpolation_respects_gaps():
    gt = Trajectory([0.0, 1.0, 2.0, 10.0, 11.0], np.arange(15.0).reshape(5, 3),
                    Rotation.from_euler("z", [[0], [90], [180], [0], [0]], degrees=True).as_quat())
    at, mask = interpolate(gt, np.array([-1.0, 0.5, 1.5, 5.0, 10.0, 12.0]))
    assert mask.tolist() == [False, True, True, False, True, False]
    np.testing.assert_allclose(at.positions[0], [1.5, 2.5, 3.5])
    yaw = Rotation.from_quat(at.quaternions[1]).as_euler("xyz", degrees=True)[2]
    assert yaw == pytest.approx(135.0)


def test_perfect_estimate_scores_zero_and_rpe_is_per_metre():
    t = np.arange(100) * 0.1
    gt = Trajectory(t, np.column_stack([t, np.zeros(100), np.zeros(100)]),
                    np.tile([0, 0, 0, 1.0], (100, 1)))
    assert evaluate(gt, gt, "none").ate_rmse_m == 0.0
    # an estimate that travels 10% too far along x: 10% translation RPE once aligned with se3
    est = Trajectory(t, gt.positions * 1.1, gt.quaternions)
    result = evaluate(gt, est, "none", rpe_delta_m=1.0)
    assert result.rpe_trans_pct == pytest.approx(10.0, rel=1e-6)
    assert result.rpe_rot_deg_per_m == pytest.approx(0.0, abs=1e-9)


def test_tracked_fraction_counts_frames_with_a_pose():
    frames = np.arange(10) * 0.1
    gt = Trajectory(np.arange(0, 1.0, 0.01), np.random.default_rng(0).normal(size=(100, 3)),
                    np.tile([0, 0, 0, 1.0], (100, 1)))
    est = gt.subset(np.isin(np.round(gt.t, 6), np.round(frames[3:], 6)))
    result = evaluate(gt, est, "sim3", frame_times=frames)
    assert (result.tracked, result.frames) == (7, 10)
    assert result.tracked_fraction == pytest.approx(0.7)


def test_eval_command_json_and_plot(data_dir, tmp_path, capsys):
    sequence = data_dir / "vamr_ex01_checkerboard736"
    est_path = tmp_path / "estimate.txt"
    write_tum(perturbed(read_tum(sequence / "groundtruth.txt"), seed=1), est_path)
    plot = tmp_path / "plot.png"
    assert main(["eval", str(sequence), str(est_path), "--json", "--plot", str(plot)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert {"ate_rmse_m", "matched", "align", "scale"} <= result.keys()
    assert result["tracked"] == 736 and result["align"] == "sim3"
    assert plot.stat().st_size > 10_000


def test_eval_command_bad_input_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 1\n")
    assert main(["eval", str(bad), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"sdvl eval: error: {bad}:3: expected t tx ty tz qx qy qz qw "
                   "(8 values), got 7")


def test_rotation_error_is_aligned_on_orientations_not_positions():
    # a camera that only rotates: the position fit is meaningless, the rotation error is not
    rng = np.random.default_rng(5)
    t = np.arange(200) * 0.03
    gt = Trajectory(t, rng.normal(0, 1e-3, (200, 3)),
                    Rotation.from_euler("xyz", np.column_stack([np.sin(t), np.cos(t), t]))
                    .as_quat())
    offset = Rotation.from_rotvec([0.4, -1.0, 2.0])
    est = Trajectory(t, rng.normal(0, 1e-3, (200, 3)), (offset * gt.rotations).as_quat())
    assert evaluate(gt, est, "sim3").rot_rmse_deg < 1e-6
