"""PNG plots of trajectories and their errors (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.metrics import Aligned
from sim.trajectory import Trajectory


def _figure(rows: int, cols: int, size: tuple[float, float]):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt, *plt.subplots(rows, cols, figsize=size)


def top_view_axes(positions: np.ndarray) -> tuple[int, int]:
    """The two axes along which a trajectory extends most (the view from 'above' it)."""
    extent = np.ptp(positions, axis=0)
    a, b = sorted(np.argsort(extent)[-2:])
    return int(a), int(b)


def plot_evaluation(aligned: Aligned, path: str | Path, title: str) -> None:
    """Top view of ground truth and aligned estimate, and the position error over time."""
    gt, est = aligned.groundtruth, aligned.estimate
    a, b = top_view_axes(gt.positions)
    names = "xyz"
    plt, fig, (ax_top, ax_err) = _figure(1, 2, (12, 5))
    ax_top.plot(gt.positions[:, a], gt.positions[:, b], "k-", lw=1.5, label="ground truth")
    ax_top.plot(est.positions[:, a], est.positions[:, b], "r-", lw=1, label="estimate (aligned)")
    ax_top.plot(*gt.positions[0, [a, b]], "go", label="start")
    ax_top.set_xlabel(f"{names[a]} [m]")
    ax_top.set_ylabel(f"{names[b]} [m]")
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.legend(loc="best")
    ax_top.set_title("trajectory, top view")
    error = np.linalg.norm(gt.positions - est.positions, axis=1)
    ax_err.plot(est.t - est.t[0], error, "r-", lw=1)
    ax_err.set_xlabel("time since first pose [s]")
    ax_err.set_ylabel("position error [m]")
    ax_err.set_title("absolute trajectory error")
    ax_err.grid(True, alpha=0.3)
    _save(plt, fig, title, path)


def _save(plt, fig, title: str, path: str | Path) -> None:
    """Title, layout and PNG file; InputError when it cannot be written."""
    fig.suptitle(title)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise InputError(f"cannot write plot: {exc.strerror}", path) from None
    finally:
        plt.close(fig)


def plot_replay(aligned: Aligned, flight: Trajectory, path: str | Path, title: str,
                ned: bool = False) -> None:
    """A replay at a glance: top view of the flight and the received poses (aligned), height
    over time (-z) and position error over time. `ned`: the world is NED, so the top view is
    east/north; otherwise it spans the two axes the flight extends most along."""
    est = aligned.estimate
    t0 = flight.t[0]
    if ned:
        (a, b), labels = (1, 0), ("east [m]", "north [m]")
    else:
        a, b = top_view_axes(flight.positions)
        labels = (f"{'xyz'[a]} [m]", f"{'xyz'[b]} [m]")
    plt, fig, (ax_top, ax_alt, ax_err) = _figure(1, 3, (16, 5))
    ax_top.plot(flight.positions[:, a], flight.positions[:, b], "k-", lw=1.5,
                label="ground truth")
    ax_top.plot(est.positions[:, a], est.positions[:, b], "r.", ms=2,
                label="received (aligned)")
    ax_top.plot(*flight.positions[0, [a, b]], "go", label="start")
    ax_top.set_xlabel(labels[0])
    ax_top.set_ylabel(labels[1])
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.legend(loc="best", fontsize=9)
    ax_top.set_title("top view")
    ax_alt.plot(flight.t - t0, -flight.positions[:, 2], "k-", lw=1.5, label="ground truth")
    ax_alt.plot(est.t - t0, -est.positions[:, 2], "r.", ms=2, label="received (aligned)")
    ax_alt.set_xlabel("time [s]")
    ax_alt.set_ylabel("height, -z [m]")
    ax_alt.set_title("height over time")
    ax_alt.legend(loc="best", fontsize=9)
    error = np.linalg.norm(aligned.groundtruth.positions - est.positions, axis=1)
    ax_err.plot(est.t - t0, error, "r-", lw=1)
    ax_err.set_xlabel("time [s]")
    ax_err.set_ylabel("position error [m]")
    ax_err.set_title(f"position error (RMSE {np.sqrt(np.mean(error**2)):.3g} m)")
    for ax in (ax_top, ax_alt, ax_err):
        ax.grid(True, alpha=0.3)
    _save(plt, fig, title, path)
