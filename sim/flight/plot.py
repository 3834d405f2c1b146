"""`sdvl fly --plot out.png`: the planned and the flown path, the autopilot's estimate and ours,
from above and over time, all in the world's frame (the autopilot's frame moved by where it
thought it was when it armed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.flight.flight_run import FlightRun
from sim.flight.scores import frame_offset
from sim.plots import _figure, _save


def _ours(run: FlightRun) -> tuple[np.ndarray, np.ndarray]:
    """(times, NED positions) of the ODOMETRY the autopilot received, by capture time."""
    if not run.sent:
        return np.zeros(0), np.zeros((0, 3))
    t = np.array([m.fields["time_usec"] / 1e6 for m in run.sent]) - run.timing.our_clock_s
    return t, np.array([[m.fields[k] for k in "xyz"] for m in run.sent])


def plot_flight(run: FlightRun, path: str | Path, title: str) -> None:
    """Top view (east, north) and height over time of: the mission's plan, the true flight,
    the autopilot's own estimate and the estimate we sent."""
    offset = frame_offset(run)
    plan = np.array(run.mission.planned_path()) + (offset if offset is not None else 0.0)
    truth = run.truth.positions
    estimates = run.record.estimates
    ap_t = np.array([e.t for e in estimates])
    ap = np.array([e.position for e in estimates]).reshape(-1, 3)
    our_t, ours = _ours(run)
    if offset is not None:
        ap, ours = ap + offset, ours + offset
    plt, fig, (ax_top, ax_height) = _figure(1, 2, (14, 6))
    ax_top.plot(plan[:, 1], plan[:, 0], "o--", color="0.6", lw=1, label="planned")
    ax_top.plot(truth[:, 1], truth[:, 0], "k-", lw=1.5, label="flown (truth)")
    ax_top.plot(ap[:, 1], ap[:, 0], "b-", lw=0.8, label="autopilot's estimate")
    ax_top.plot(ours[:, 1], ours[:, 0], "r.", ms=1.5, label="ours (received)")
    ax_top.set_xlabel("east [m]")
    ax_top.set_ylabel("north [m]")
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.set_title("top view")
    ax_height.plot(run.truth.t, -truth[:, 2], "k-", lw=1.5, label="flown (truth)")
    ax_height.plot(ap_t, -ap[:, 2], "b-", lw=0.8, label="autopilot's estimate")
    ax_height.plot(our_t, -ours[:, 2], "r.", ms=1.5, label="ours (received)")
    for r in run.steps:
        ax_height.axvline(r.started, color="0.85", lw=0.8)
    ax_height.set_xlabel("time since the autopilot booted [s] (grey: mission steps)")
    ax_height.set_ylabel("height, -z [m]")
    ax_height.set_title("height over time")
    for ax in (ax_top, ax_height):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=9)
    _save(plt, fig, title, path)
