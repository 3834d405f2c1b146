"""`sdvl fly --frames-csv FILE`: one row per frame of a virtual-clock flight, to see where and
why a flight went wrong: the tracker's counts and its pose in its map, the estimate we sent
with its standard deviation, and where the vehicle truly was (NED, the world's frame, as the
estimate once the autopilot's origin is set)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

COLUMNS = ("t", "quality", "matches", "attempts", "inliers", "keyframe", "new_segment",
           "relocalized", "map_x", "map_y", "map_z", "sent", "x", "y", "z", "std_x", "std_y",
           "std_z", "true_x", "true_y", "true_z")
NO_XYZ = (np.nan, np.nan, np.nan)


def frame_details(result: object, estimate: object | None) -> dict:
    """What a row adds to the companion's record of a frame: the tracker's counts, its
    camera position in its map (NaN without a pose), our position and its std (NaN when
    nothing was sent)."""
    pose = result.T_w_c[:3, 3] if result.T_w_c is not None else NO_XYZ
    ours, std = NO_XYZ, NO_XYZ
    if estimate is not None:
        ours = estimate.position
        std = np.sqrt(np.maximum(np.diag(estimate.pose_covariance)[:3], 0.0))
    return {"matches": result.n_matches, "attempts": result.n_attempts,
            "inliers": result.n_inliers, "keyframe": int(result.keyframe),
            "relocalized": int(getattr(result, "relocalized", False)),
            "map_position": tuple(pose), "position": tuple(ours), "std": tuple(std)}


def write_flight_frames(path: Path, run: object) -> None:
    """The rows of a FlightRun (one per tracked frame) as CSV, each with the true position at
    the frame's time."""
    truth = run.truth
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(COLUMNS)
        for r in run.rows:
            true = [np.interp(r["t_source"], truth.t, truth.positions[:, k]) for k in range(3)]
            ours = (f"{v:.4f}" for v in (*r["position"], *r["std"], *true))
            writer.writerow([f"{r['t_source']:.3f}", r["quality"], r["matches"], r["attempts"],
                             r["inliers"], r["keyframe"], int(r["new_segment"]),
                             r["relocalized"], *(f"{v:.4f}" for v in r["map_position"]),
                             int(r["sent"]), *ours])
