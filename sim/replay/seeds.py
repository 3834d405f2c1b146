"""`sdvl replay PRESET --seeds 0-4`: one synthetic flight flown with several seeds (world,
sensor noise and the autopilot's compass bias drawn anew each time), a line per seed and the
Monte-Carlo summary.

Each flight draws its own constants (world, sensor biases, the compass bias that turns the
autopilot's heading frame against true north); a flight's NEES is scored in that frame
(sim/replay/fusion_scores.py), and over flights the average NEES of the runs (ANEES) says
whether the covariance is honest in general.
"""

from __future__ import annotations

import numpy as np

from sdvl.errors import InputError

MAX_SEEDS = 100


def parse_seeds(text: str) -> list[int]:
    """Seeds from '0-4', '1,3,7' or a mix ('0-2,9'), in the order given, without repeats."""
    seeds: list[int] = []
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        try:
            lo = int(first)
            hi = int(last) if dash else lo
        except ValueError:
            raise InputError(f"--seeds: '{part.strip()}' is not a seed or a range like 0-4 "
                             "(seeds are whole numbers >= 0)") from None
        if hi < lo:
            raise InputError(f"--seeds: the range '{part.strip()}' is empty")
        seeds += [s for s in range(lo, hi + 1) if s not in seeds]
        if len(seeds) > MAX_SEEDS:
            raise InputError(f"--seeds: at most {MAX_SEEDS} seeds")
    return seeds


def _values(reports: list[dict], key: str) -> list[float]:
    return [r[key] for r in reports if r.get(key) is not None]


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _extreme(values: list[float], fn) -> float | None:
    return float(fn(values)) if values else None


def summarize(reports: list[dict]) -> dict:
    """Over the runs: mean and worst ATE, worst heading and publication delay, and the average
    NEES (ANEES) with the range of the single runs'."""
    out = {"runs": len(reports)}
    for key in ("ate_rmse_m", "ate_pct_distance", "velocity_rmse_m_s"):
        out[f"{key}_mean"] = _mean(_values(reports, key))
        out[f"{key}_max"] = _extreme(_values(reports, key), max)
    for key in ("heading_max_deg", "heading_frame_max_deg", "aligned_after_takeoff_s",
                "overconfident_fraction"):
        out[f"{key}_max"] = _extreme(_values(reports, key), max)
    out["tracked_fraction_min"] = _extreme(_values(reports, "tracked_fraction"), min)
    for key in ("nees_position", "nees_velocity"):
        values = _values(reports, key)
        out[f"a{key}"] = _mean(values)
        out[f"{key}_min"] = _extreme(values, min)
        out[f"{key}_max"] = _extreme(values, max)
    return out


def _cell(value: float | None, fmt: str, width: int) -> str:
    return ("n/a" if value is None else format(value, fmt)).rjust(width)


def format_seeds(seeds: list[int], reports: list[dict], summary: dict) -> str:
    """A table line per seed and the summary lines."""
    lines = ["seed  tracked   ATE m  ATE %  heading max deg  NEES pos  NEES vel  >3 sigma"
             "    aligned  compass",
             "                               true  AP frame                                "
             "    s after bias deg",
             " " * 78 + "take-off"]
    for seed, r in zip(seeds, reports, strict=True):
        lines.append(f"{seed:>4} {_cell(r['tracked_fraction'], '.1%', 8)}"
                     f"{_cell(r['ate_rmse_m'], '.4f', 8)}{_cell(r['ate_pct_distance'], '.2f', 7)}"
                     f"{_cell(r['heading_max_deg'], '.2f', 7)}"
                     f"{_cell(r['heading_frame_max_deg'], '.2f', 10)}"
                     f"{_cell(r['nees_position'], '.2f', 10)}{_cell(r['nees_velocity'], '.2f', 10)}"
                     f"{_cell(r['overconfident_fraction'], '.1%', 10)}"
                     f"{_cell(r['aligned_after_takeoff_s'], '.2f', 11)}"
                     f"{_cell(r['compass_bias_deg'], '+.2f', 9)}")
    s = summary
    lines += [
        f"over {s['runs']} seeds: ATE mean {_cell(s['ate_rmse_m_mean'], '.4f', 0)} m, max "
        f"{_cell(s['ate_rmse_m_max'], '.4f', 0)} m ({_cell(s['ate_pct_distance_max'], '.2f', 0)}"
        f"% of the distance flown); heading max {_cell(s['heading_max_deg_max'], '.2f', 0)} deg "
        f"({_cell(s['heading_frame_max_deg_max'], '.2f', 0)} in the autopilot's heading frame); "
        f"aligned at most {_cell(s['aligned_after_takeoff_s_max'], '.2f', 0)} s after the "
        f"take-off, errors beyond 3 sigma at most "
        f"{_cell(s['overconfident_fraction_max'], '.1%', 0)}",
        f"  ANEES per dof: position {_cell(s['anees_position'], '.2f', 0)} (runs "
        f"{_cell(s['nees_position_min'], '.2f', 0)}-{_cell(s['nees_position_max'], '.2f', 0)}), "
        f"velocity {_cell(s['anees_velocity'], '.2f', 0)} (runs "
        f"{_cell(s['nees_velocity_min'], '.2f', 0)}-{_cell(s['nees_velocity_max'], '.2f', 0)})"]
    return "\n".join(lines)
