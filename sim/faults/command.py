"""`sdvl faults`: fault injection against the service, and the long-run memory check.

    sdvl faults soak [PRESET] --minutes M    the service on a flight flown back and forth for M
                                              minutes in real time; RSS over time
"""

from __future__ import annotations

import argparse
import json

from sdvl.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl faults`."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    soak = sub.add_parser("soak", help="RSS of the service over a long real-time flight")
    soak.add_argument("preset", nargs="?", default="survey-down",
                      help="synthetic preset flown back and forth (default survey-down)")
    soak.add_argument("--minutes", type=float, default=60.0)
    soak.add_argument("--seed", type=int, default=0)
    soak.add_argument("--size", default=None, metavar="WxH", help="render size (default the "
                                                                  "preset's, 640x480)")
    soak.add_argument("--tracemalloc-from", type=float, default=None, metavar="MIN",
                      help="trace Python allocations from this minute to the end and print "
                           "the largest growth (slows the service)")
    soak.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    """Dispatch to the action."""
    return _soak(args)


def _size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must be WIDTHxHEIGHT, got '{text}'") from None
    return width, height


def _soak(args: argparse.Namespace) -> int:
    from daemon.run_command import setup_logging
    from sim.faults.soak import soak
    from sim.synth.flight import synthetic_sequence

    if args.minutes <= 0:
        raise InputError("--minutes must be positive")
    setup_logging("warning")
    sequence = synthetic_sequence(args.preset, size=_size(args.size), seed=args.seed)
    result = soak(sequence, args.minutes, trace_from_min=args.tracemalloc_from)
    ten = result.rss_at(min(10.0, args.minutes))
    end = result.samples[-1][1] if result.samples else float("nan")
    summary = {"preset": args.preset, "minutes": args.minutes, "rss_10min_mb": ten,
               "rss_end_mb": end, "growth_after_10min": end / ten - 1.0,
               "frames_offered": result.frames_offered, "frames_tracked": result.frames_tracked,
               "sent": result.sent, "exit_code": result.exit_code, "samples": result.samples}
    if args.json:
        print(json.dumps(summary))
        return result.exit_code
    print(f"soak {args.preset} {args.minutes:g} min: RSS {ten:.0f} MB at 10 min (or the end of "
          f"a shorter run), {end:.0f} MB at the end ({100 * (end / ten - 1):+.1f}%)")
    print(f"  frames offered {result.frames_offered}, tracked {result.frames_tracked}, vision "
          f"messages sent {result.sent}, exit code {result.exit_code}")
    print("  RSS (MB) by minute: " + ", ".join(
        f"{m:.0f}: {r:.0f}" for m, r in result.samples if abs(m - round(m)) < 0.09))
    for line in result.top_growth:
        print("  grew " + line)
    return result.exit_code
