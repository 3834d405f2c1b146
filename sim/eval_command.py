"""`sdvl eval GROUNDTRUTH ESTIMATE`: accuracy of a trajectory file against ground truth."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.metrics import ALIGNMENTS, align_trajectories, evaluate
from sim.trajectory import Trajectory, read_tum


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl eval`."""
    parser.add_argument("groundtruth", type=Path,
                        help="ground truth: a TUM file, or a sequence folder (then the tracked "
                             "fraction is counted against its frames)")
    parser.add_argument("estimate", type=Path, help="estimated trajectory, TUM format")
    parser.add_argument("--align", choices=ALIGNMENTS, default="sim3",
                        help="alignment before scoring (default sim3: monocular scale is free)")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames the estimate could have covered")
    parser.add_argument("--rpe-delta", type=float, default=None, metavar="METRES",
                        help="RPE segment length (default: a tenth of the path)")
    parser.add_argument("--plot", type=Path, default=None, metavar="OUT.png",
                        help="write a PNG with the top view and the error over time")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def load_groundtruth(path: Path) -> tuple[Trajectory, np.ndarray | None]:
    """Ground truth from a TUM file or a sequence folder, and the folder's frame times."""
    if path.is_dir():
        from sim.datasets import open_sequence

        sequence = open_sequence(path)
        if sequence.groundtruth is None:
            raise InputError("sequence has no ground truth", path)
        return sequence.groundtruth, sequence.timestamps
    return read_tum(path), None


def format_report(d: dict) -> str:
    """Human-readable lines for an evaluation dictionary."""
    lines = [f"matched poses   {d['matched']}"]
    if d["tracked_fraction"] is not None:
        lines.append(f"tracked         {d['tracked']}/{d['frames']} "
                     f"({100 * d['tracked_fraction']:.1f}%)")
    lines += [
        f"alignment       {d['align']} (scale {d['scale']:.6g})",
        f"ATE RMSE        {d['ate_rmse_m']:.6f} m   (mean {d['ate_mean_m']:.6f}, median "
        f"{d['ate_median_m']:.6f}, max {d['ate_max_m']:.6f})",
        f"rotation RMSE   {d['rot_rmse_deg']:.3f} deg",
        f"path length     {d['path_length_m']:.3f} m",
    ]
    if d["rpe_trans_pct"] is not None:
        lines.append(f"RPE             {d['rpe_trans_pct']:.3f} % translation, "
                     f"{d['rpe_rot_deg_per_m']:.4f} deg/m (segments of {d['rpe_delta_m']:.3f} m)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Score the estimate and print the report."""
    groundtruth, frame_times = load_groundtruth(args.groundtruth)
    estimate = read_tum(args.estimate)
    if args.frames is not None and args.frames <= 0:
        raise InputError("--frames must be positive")
    result = evaluate(groundtruth, estimate, args.align, args.frames, args.rpe_delta,
                      frame_times=frame_times).to_dict()
    if args.plot is not None:
        from sim.plots import plot_evaluation

        aligned = align_trajectories(groundtruth, estimate, args.align)
        plot_evaluation(aligned, args.plot, f"{args.estimate.name} vs {args.groundtruth.name}")
    print(json.dumps(result) if args.json else format_report(result))
    return 0
