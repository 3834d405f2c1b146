"""`sdvl track-table`: run tracker configurations over sequences and print the table of ATE
RMSE, frames tracked, tracking ms and mapping ms (like thesis tables 7.1-7.4), with the
original C++ SDVL figures from the shared data README beside the real sequences."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from calib.errors import InputError

DEFAULT_SEQUENCES = ("vamr_ex01_checkerboard736", "kitti00_first200", "tum_fr1_rpy")
# the thesis' configuration axes available here (ORB matching is not implemented)
CONFIGS = {
    "patch": {"outlier_rejection": False},
    "patch+rej": {"outlier_rejection": True},
    "patch+ba": {"local_ba": True, "outlier_rejection": False},
    "patch+ba+rej": {"local_ba": True, "outlier_rejection": True},
}
# tracker presets of the vo package used as the base config of sequences with this prefix
BASE_PRESETS = {"kitti": "kitti_10hz.toml"}
# original C++ SDVL (shared data README): frames tracked, ATE RMSE m, tracking ms median
ORIGINAL = {
    "vamr_ex01_checkerboard736": ("734/736", "0.0047", "3.2"),
    "kitti00_first200": ("200/200", "1.50", "5.7"),
    "tum_fr1_rpy": ("673/723", "0.044-0.059", "2.5-3.2"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl track-table`."""
    parser.add_argument("sequences", nargs="*", default=list(DEFAULT_SEQUENCES),
                        help="sequence folders, shared-data names or synthetic preset names "
                             f"(default: {' '.join(DEFAULT_SEQUENCES)})")
    parser.add_argument("--configs", default=",".join(CONFIGS),
                        help=f"comma-separated configurations out of {', '.join(CONFIGS)}")
    parser.add_argument("--threaded", action="store_true", help="mapping in its own thread")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N")
    parser.add_argument("--json", action="store_true", help="one JSON object per row")


def run(args: argparse.Namespace) -> int:
    """Track every sequence with every configuration; print the table row by row."""
    from sim.track_command import resolve_sequence, track_sequence
    from vo.config import TrackerConfig

    names = [c.strip() for c in args.configs.split(",") if c.strip()]
    unknown = [c for c in names if c not in CONFIGS]
    if unknown or not names:
        raise InputError(f"unknown configuration {', '.join(unknown) or '(none)'} "
                         f"(known: {', '.join(CONFIGS)})")
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    if not args.json:
        print(header())
    for seq_name in args.sequences:
        sequence = resolve_sequence(seq_name)
        for name in names:
            config = TrackerConfig.from_dict({**base_parameters(seq_name), **CONFIGS[name]})
            report, _ = track_sequence(sequence, config, args.threaded, args.max_frames,
                                       quiet=True)
            row = table_row(seq_name, name, report)
            print(json.dumps(row) if args.json else format_row(row), flush=True)
        if not args.json and seq_name in ORIGINAL:
            tracked, ate, ms = ORIGINAL[seq_name]
            print(f"{seq_name:<28} {'original C++':<14} {tracked:>9} {ate:>12} {'':>10} "
                  f"{ms:>9} {'':>9}")
    return 0


def base_parameters(sequence: str) -> dict:
    """Parameters of the vo preset for this kind of sequence (BASE_PRESETS), else none."""
    import tomllib

    import vo

    for prefix, file in BASE_PRESETS.items():
        if Path(sequence).name.startswith(prefix):
            data = tomllib.loads((Path(vo.__file__).parent / "presets" / file).read_text())
            return data.get("tracker", data)
    return {}


def table_row(sequence: str, config: str, report: dict) -> dict:
    """The table's numbers from a `sdvl track` report."""
    stages = report["stages"]
    return {"sequence": sequence, "config": config, "frames": report["frames"],
            "tracked": report["tracked"], "segments": report["segments"],
            "ate_rmse_m": report["ate_rmse_m"],
            "longest_segment_ate_rmse_m": report["longest_segment_ate_rmse_m"],
            "track_ms_median": report["track_ms_median"],
            "track_ms_p95": report["track_ms_p95"], "mapping_ms_median": stages.get("mapping")}


def header() -> str:
    """Column titles of the text table."""
    return (f"{'sequence':<28} {'config':<14} {'tracked':>9} {'ATE m':>12} {'segments':>10} "
            f"{'track ms':>9} {'map ms':>9}")


def format_row(r: dict) -> str:
    """One line of the text table (ATE over all segments; several segments are only
    indicative, each having its own scale)."""
    def num(x, fmt):
        return "n/a" if x is None else format(x, fmt)

    return (f"{r['sequence']:<28} {r['config']:<14} {r['tracked']:>4}/{r['frames']:<4} "
            f"{num(r['ate_rmse_m'], '12.4f')} {r['segments']:>10} "
            f"{num(r['track_ms_median'], '9.2f')} {num(r['mapping_ms_median'], '9.2f')}")
