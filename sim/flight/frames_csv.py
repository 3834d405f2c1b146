"""`sdvl fly --frames-csv FILE`: one row per frame of a virtual-clock flight, to see where and
why a flight went wrong: the tracker's columns of `sdvl track --frames-csv` (but the error,
which is the flight's truth here), its camera position in its map, the estimate we sent with
its standard deviation, and where the vehicle truly was (NED, the world's frame, as the
estimate once the autopilot's origin is set)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from sim.track_command import FRAME_COLUMNS, frame_row

TRACKER_COLUMNS = tuple(c for c in FRAME_COLUMNS if c != "error_m")
XYZ_COLUMNS = ("map_x", "map_y", "map_z", "x", "y", "z", "std_x", "std_y", "std_z", "true_x",
               "true_y", "true_z")
COLUMNS = (*TRACKER_COLUMNS, "sent", *XYZ_COLUMNS)
NO_XYZ = (np.nan, np.nan, np.nan)


def frame_details(result: object, estimate: object | None) -> dict:
    """A frame's row but the truth: the tracker's columns, its camera position in its map
    (NaN without a pose), our position and its std (NaN when nothing was sent)."""
    row = {k: v for k, v in frame_row(result).items() if k in TRACKER_COLUMNS}
    pose = result.T_w_c[:3, 3] if result.T_w_c is not None else NO_XYZ
    ours, std = NO_XYZ, NO_XYZ
    if estimate is not None:
        ours = estimate.position
        std = np.sqrt(np.maximum(np.diag(estimate.pose_covariance)[:3], 0.0))
    row["sent"] = int(estimate is not None)
    row.update(zip(XYZ_COLUMNS[:9], (*pose, *ours, *std), strict=True))
    return row


def write_flight_frames(path: Path, run: object) -> None:
    """The frame rows of a FlightRun (`details` of each of its rows) as CSV, each with the
    true position at the frame's time."""
    truth = run.truth
    t = np.array([r["t_source"] for r in run.rows])
    true = np.column_stack([np.interp(t, truth.t, truth.positions[:, k]) for k in range(3)])
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(COLUMNS))
        writer.writeheader()
        for r, xyz in zip(run.rows, true, strict=True):
            row = {**r["details"], **dict(zip(XYZ_COLUMNS[9:], xyz, strict=True))}
            row.update({k: f"{row[k]:.4f}" for k in XYZ_COLUMNS})
            writer.writerow(row)
