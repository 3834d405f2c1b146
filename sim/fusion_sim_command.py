"""`sdvl fusion-sim`: the fusion filter on a simulated take-off + survey flight: accuracy after
convergence, convergence time, NEES and the filter's time per frame (median, p95)."""

from __future__ import annotations

import argparse
import json

import numpy as np

from daemon.config import MountingConfig
from daemon.fusion.estimator import FusionEstimator
from sim import fusion_sim


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl fusion-sim`."""
    parser.add_argument("--sensors", choices=list(fusion_sim.SENSOR_VARIANTS), default="full",
                        help="which autopilot sensors exist (default: IMU, rangefinder, baro)")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--legs", type=int, default=4, help="survey legs of 30 m")
    parser.add_argument("--reset-at", type=float, default=40.0,
                        help="tracker lost for 0.5 s at this time, then a new map (<0: never)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    """Simulate, filter, score, print."""
    lost = ((args.reset_at, args.reset_at + 0.5),) if args.reset_at >= 0 else ()
    tracker = fusion_sim.TrackerOptions(weak=((20.0, 24.0),), lost=lost)
    flight = fusion_sim.simulate(fusion_sim.SENSOR_VARIANTS[args.sensors], tracker,
                                 seed=args.seed, truth=fusion_sim.survey_flight(legs=args.legs))
    texts: list[str] = []
    estimator = FusionEstimator(fusion_sim.fusion_config(), MountingConfig(),
                                report=texts.append)
    timings: list[float] = []
    estimates = fusion_sim.run(flight, estimator, timings)
    score = fusion_sim.score(flight, estimates)
    ms = 1000 * np.array(timings)
    report = {**score.to_dict(), "frames": len(estimates), "reset_counter": estimator.reset_counter,
              "replays": estimator.timeline.replays, "frame_ms_median": float(np.median(ms)),
              "frame_ms_p95": float(np.percentile(ms, 95)), "texts": texts}
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"sensors {args.sensors}, seed {args.seed}: published {score.published}/"
          f"{len(estimates)} frames, first at {score.first_published_s:.2f} s")
    print(f"  position RMSE {score.position_rmse_m:.3f} m = {score.position_pct:.2f}% of "
          f"{score.distance_m:.0f} m flown; heading RMS {score.heading_rms_deg:.2f} deg")
    print(f"  velocity RMSE {score.velocity_rmse_m_s:.3f} m/s; NEES per dof: position "
          f"{score.nees_position:.2f}, velocity {score.nees_velocity:.2f}; reset_counter "
          f"{estimator.reset_counter}")
    print(f"  filter time per frame: median {report['frame_ms_median']:.2f} ms, "
          f"p95 {report['frame_ms_p95']:.2f} ms")
    for text in texts:
        print(f"  STATUSTEXT: {text}")
    return 0
