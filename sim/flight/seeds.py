"""`sdvl fly --seeds 0-19`: a line per seed and the summary over the flights: how many were
ready, the distribution of when the autopilot started using our estimate, and the worst hold
drift, corner error and height step (issue 27's acceptance is 'on every seed')."""

from __future__ import annotations

import numpy as np

HEADER = ("seed  verdict    armed  extnav s  LOITER  corner  height wander, error  height"
          "  fail-    ATE m  NEES  VISO_DELAY\n"
          "                         from      drift   max m   truth  autopilot  ours    step"
          "  safes           pos   suggested\n"
          "                         lift-off  m                                          m")


def _cell(value: float | None, fmt: str, width: int) -> str:
    return ("n/a" if value is None else format(value, fmt)).rjust(width)


def _short(report: dict) -> str:
    text = report["verdict"]
    if text.startswith("READY"):
        return "READY-G" if report["ready_guided"] else "READY-L"
    return text.split(":")[0].replace("NOT ", "NOT-")


def format_seed_table(seeds: list[int], reports: list[dict], summary: dict) -> str:
    """The table and the summary lines, then each seed's verdict in full."""
    lines = [HEADER]
    for seed, r in zip(seeds, reports, strict=True):
        e = r["expert"]
        lines.append(f"{seed:>4}  {_short(r):<9}{'yes' if r['armed'] else 'no':>6}"
                     f"{_cell(r['extnav_after_takeoff_s'], '+.1f', 10)}"
                     f"{_cell(r['hold_drift_m'], '.2f', 8)}"
                     f"{_cell(r['corner_error_max_m'], '.2f', 8)}"
                     f"{_cell(r['height_wander_m'], '.2f', 8)}"
                     f"{_cell(r['autopilot_height_error_m'], '.2f', 11)}"
                     f"{_cell(r['our_height_error_m'], '.2f', 6)}"
                     f"{_cell(r['height_step_max_m'], '.2f', 8)}{len(r['failsafes']):>7}"
                     f"{_cell(e['ate_rmse_m'], '.3f', 9)}{_cell(e['nees_position'], '.2f', 6)}"
                     f"{_cell(r['suggested_viso_delay_ms'], '.0f', 12)}")
    s = summary
    extnav = s["extnav_after_takeoff_s"]
    lines += [
        f"over {s['runs']} seeds: ready for LOITER {s['ready_loiter']}, for GUIDED "
        f"{s['ready_guided']}, armed {s['armed']}; failsafes on {s['with_failsafe']} seeds",
        f"  the autopilot used our estimate from lift-off: min {_cell(extnav['min'], '+.1f', 0)}"
        f" / median {_cell(extnav['median'], '+.1f', 0)} / max {_cell(extnav['max'], '+.1f', 0)}"
        f" s ({extnav['n']} seeds)",
        f"  worst: LOITER drift {_cell(s['hold_drift_m_max'], '.3f', 0)} m, corner "
        f"{_cell(s['corner_error_max_m'], '.3f', 0)} m, height wander "
        f"{_cell(s['height_wander_m_max'], '.3f', 0)} m (the autopilot's height off by "
        f"{_cell(s['autopilot_height_error_m_max'], '.3f', 0)} m, ours by "
        f"{_cell(s['our_height_error_m_max'], '.3f', 0)} m), height step "
        f"{_cell(s['height_step_max_m_max'], '.3f', 0)} m; ANEES position "
        f"{_cell(s['anees_position'], '.2f', 0)}",
        "verdicts:"]
    lines += [f"  {seed:>4}  {r['verdict']}" for seed, r in zip(seeds, reports, strict=True)]
    return "\n".join(lines)


def _values(reports: list[dict], key: str) -> list[float]:
    return [r[key] for r in reports if r.get(key) is not None]


def summarize_flights(reports: list[dict]) -> dict:
    """Counts and extremes over the flights (None where no flight had the figure)."""
    extnav = _values(reports, "extnav_after_takeoff_s")
    nees = [r["expert"]["nees_position"] for r in reports
            if r["expert"].get("nees_position") is not None]
    corners = [r["corner_error_max_m"] for r in reports if r["corners"]]
    return {
        "runs": len(reports),
        "ready_loiter": sum(r["ready_loiter"] for r in reports),
        "ready_guided": sum(r["ready_guided"] for r in reports),
        "armed": sum(r["armed"] for r in reports),
        "with_failsafe": sum(bool(r["failsafes"]) for r in reports),
        "extnav_after_takeoff_s": {
            "n": len(extnav), "min": min(extnav, default=None),
            "median": float(np.median(extnav)) if extnav else None,
            "max": max(extnav, default=None)},
        "hold_drift_m_max": max(_values(reports, "hold_drift_m"), default=None),
        "corner_error_max_m": (None if not corners or None in corners else max(corners)),
        **{f"{key}_max": max(_values(reports, key), default=None)
           for key in ("height_step_max_m", "height_wander_m", "autopilot_height_error_m",
                       "our_height_error_m")},
        "anees_position": float(np.mean(nees)) if nees else None,
    }
