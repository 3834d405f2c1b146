"""PNG plots of trajectories and their errors (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.errors import InputError
from sim.metrics import Aligned


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
    fig.suptitle(title)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise InputError(f"cannot write plot: {exc.strerror}", path) from None
    finally:
        plt.close(fig)
