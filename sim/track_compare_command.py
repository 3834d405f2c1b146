"""`sdvl track-compare --against REV SEQUENCE[@CONFIG]...`: this checkout's tracker timed side by
side with an earlier revision's, on the same machine in the same run (timings depend on the
machine and its load: only such ratios compare).

The revision is exported (`git archive`) into the cache folder once and run with this
interpreter (its packages first on the path). Each round runs `sdvl track SEQUENCE --json` with
either tracker, in alternating order, after one untimed round that compiles and loads both
sides' kernels. Per sequence it prints each stage's median and p95 (ms over the frames that ran
it; the median of the rounds) for both and the ratio after/before (median of the rounds'
ratios), then whether the output changed: frames tracked, map segments, ATE and the largest
difference between the two trajectories.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.disk_cache import cache_root
from sim.shared_data import shared_data_dir

ROOT = Path(__file__).resolve().parents[1]
SIDES = ("before", "after")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl track-compare`."""
    parser.add_argument("sequences", nargs="+", metavar="SEQUENCE[@CONFIG]",
                        help="sequences (as for sdvl track), each with an optional tracker "
                             "config file, relative to each side's checkout "
                             "(kitti00_first200@vo/presets/kitti_10hz.toml)")
    parser.add_argument("--against", required=True, metavar="REV",
                        help="the git revision to compare with (before)")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds (default 3)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N")
    parser.add_argument("--json", action="store_true", help="print one JSON object at the end")


@dataclass
class Side:
    """One tracker's runs on one sequence: its `sdvl track --json` reports."""

    reports: list[dict] = field(default_factory=list)
    trajectory: Path | None = None


def run(args: argparse.Namespace) -> int:
    """Time both trackers on every sequence and print the comparison."""
    if args.rounds < 1 or (args.max_frames is not None and args.max_frames < 1):
        raise InputError("--rounds and --max-frames must be positive")
    roots = {"before": export_revision(args.against), "after": ROOT}
    specs = [parse_spec(s) for s in args.sequences]
    runs = {spec: {side: Side() for side in SIDES} for spec in specs}
    with tempfile.TemporaryDirectory(prefix="sdvl-compare-") as tmp:
        for round_ in range(args.rounds + 1):  # round 0 compiles and loads the kernels
            for spec in specs:
                order = SIDES if round_ % 2 else SIDES[::-1]
                for side in order:
                    out = Path(tmp) / f"{side}-{len(runs[spec][side].reports)}.txt"
                    report = track_once(roots[side], spec, args.max_frames, out)
                    if round_ > 0:
                        runs[spec][side].reports.append(report)
                        runs[spec][side].trajectory = runs[spec][side].trajectory or out
        summary = {f"{seq}@{cfg}" if cfg else seq: compare(runs[(seq, cfg)])
                   for seq, cfg in specs}
    if args.json:
        print(json.dumps({"against": args.against, "rounds": args.rounds,
                          "sequences": summary}))
    else:
        print(format_summary(args.against, args.rounds, summary))
    return 0


def parse_spec(spec: str) -> tuple[str, str | None]:
    """(sequence, config or None) of SEQUENCE[@CONFIG]."""
    seq, _, config = spec.partition("@")
    if not seq:
        raise InputError(f"'{spec}': expected SEQUENCE or SEQUENCE@CONFIG")
    return seq, config or None


def export_revision(rev: str) -> Path:
    """A folder holding the source of git revision `rev` of this checkout (exported once)."""
    try:
        sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", f"{rev}^{{commit}}"],
                             capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError) as exc:
        raise InputError(f"--against {rev}: not a revision of the git checkout at {ROOT}") from exc
    folder = cache_root("revisions") / sha
    if not (folder / "vo").is_dir():
        folder.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", sha],
                                 capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def track_once(root: Path, spec: tuple[str, str | None], max_frames: int | None,
               out: Path) -> dict:
    """`sdvl track --json` of the checkout at root (its packages first on the path): the
    report, the trajectory written to out."""
    seq, config = spec
    argv = [sys.executable, "-m", "sdvl.cli", "track", seq, "--json", "--quiet", "--out", str(out)]
    if config:
        argv += ["--config", config]
    if max_frames:
        argv += ["--max-frames", str(max_frames)]
    env = dict(os.environ, PYTHONPATH=str(root), SDVL_DATA=str(shared_data_dir()))
    done = subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise InputError(f"sdvl track {seq} failed in {root}: {done.stderr.strip()[-500:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(sides: dict[str, Side]) -> dict:
    """Per stage the medians over the rounds of both sides' median and p95 and of the rounds'
    ratios; the output of both (tracked, segments, ATE) and the trajectories' difference."""
    before, after = sides["before"].reports, sides["after"].reports
    stages = sorted({s for r in before + after for s in r["stages"]})
    table = {}
    for stage in stages:
        row = {}
        for name, reports in (("before", before), ("after", after)):
            row[name] = _median([r["stages"].get(stage) for r in reports])
            row[f"{name}_p95"] = _median([r["stages_p95"].get(stage) for r in reports])
        row["ratio"] = _median([a["stages"][stage] / b["stages"][stage]
                                for b, a in zip(before, after, strict=True)
                                if stage in a["stages"] and stage in b["stages"]
                                and b["stages"][stage] > 0])
        table[stage] = row
    output = {name: {k: reports[0].get(k) for k in ("tracked", "segments", "ate_rmse_m")}
              for name, reports in (("before", before), ("after", after))}
    return {"stages": table, "output": output,
            "pose_difference": trajectory_difference(sides["before"].trajectory,
                                                     sides["after"].trajectory)}


def _median(values: list[float | None]) -> float | None:
    """Median of the values that exist (None without any)."""
    present = [v for v in values if v is not None]
    return statistics.median(present) if present else None


def trajectory_difference(a: Path | None, b: Path | None) -> float | None:
    """Largest difference of any number of two TUM trajectories (times, positions, unit
    quaternions; inf when their lengths differ, None when either is missing)."""
    if a is None or b is None or not a.exists() or not b.exists():
        return None
    x, y = np.loadtxt(a, ndmin=2), np.loadtxt(b, ndmin=2)
    return float(np.abs(x - y).max()) if x.shape == y.shape else float("inf")


def format_summary(against: str, rounds: int, summary: dict) -> str:
    """The comparison as text: a table of stages per sequence, then its output."""
    lines = [f"this checkout (after) against {against} (before), {rounds} rounds interleaved; ms "
             "per frame: median of the rounds of each stage's median and p95"]
    for name, s in summary.items():
        lines += ["", f"sequence {name}",
                  f"{'stage':<12} {'before':>8} {'p95':>8} {'after':>8} {'p95':>8} {'ratio':>7}"]
        for stage, row in s["stages"].items():
            cells = [row["before"], row["before_p95"], row["after"], row["after_p95"]]
            lines.append(f"{stage:<12} " + " ".join(_cell(c, 8) for c in cells)
                         + " " + _cell(row["ratio"], 7, ".3f"))
        track = s["stages"].get("track")
        if track and track["before"] and track["after"]:
            lines.append(f"p95/median  before {track['before_p95'] / track['before']:.2f}, "
                         f"after {track['after_p95'] / track['after']:.2f}")
        b, a = s["output"]["before"], s["output"]["after"]
        diff = s["pose_difference"]
        lines.append(f"output      tracked {b['tracked']} -> {a['tracked']}, segments "
                     f"{b['segments']} -> {a['segments']}, ATE {_cell(b['ate_rmse_m'], 0, '.4f')}"
                     f" -> {_cell(a['ate_rmse_m'], 0, '.4f')} m, trajectories differ by at most "
                     + ("n/a" if diff is None else f"{diff:.1e}"))
    return "\n".join(lines)


def _cell(value: float | None, width: int, fmt: str = ".2f") -> str:
    """A number right-aligned, '-' when missing."""
    return f"{'-' if value is None else format(value, fmt):>{width}}"
