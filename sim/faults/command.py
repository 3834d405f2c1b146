"""`sdvl faults`: fault injection against the service, and the long-run memory check.

    sdvl faults scenarios [NAME...]   issue 28's link faults on a simulated survey, in lockstep
                                      through the service's receiving side and the fusion
    sdvl faults fuzz --packets N      seeded fuzzed/mutated packets over as many flights as it
                                      takes, the same scores summed
    sdvl faults soak [PRESET]         the service on a flight flown back and forth for
                                      --minutes in real time; RSS over time
"""

from __future__ import annotations

import argparse
import json

from sdvl.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl faults`."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    from sim.faults.scenarios import FUZZ_KINDS, SCENARIOS

    scenarios = sub.add_parser("scenarios", help="link fault scenarios: crashes, NaN, stale, "
                                                 "errors beyond 3 sigma, recovery")
    scenarios.add_argument("names", nargs="*", metavar="NAME",
                           help=f"scenarios (default all): {', '.join(SCENARIOS)}")
    scenarios.add_argument("--window", nargs=2, type=float, default=(30.0, 40.0),
                           metavar=("FROM", "TO"), help="the fault's seconds of the flight "
                           "(default 30 40; some scenarios have their own length)")
    fuzz = sub.add_parser("fuzz", help="seeded fuzzed/mutated packets, scores summed")
    fuzz.add_argument("--packets", type=int, default=100_000,
                      help="fuzzed or mutated packets to send (default 100000)")
    by = fuzz.add_mutually_exclusive_group()
    by.add_argument("--by-kind", action="store_true",
                    help="a row per kind of fuzz (" + ", ".join(FUZZ_KINDS) + "), each with "
                         "--packets packets: which of them the fusion does not survive")
    by.add_argument("--by-field", action="store_true",
                    help="a row per field of each message type the autopilot streams, each "
                         "with --packets packets of only that field changed (of 10 %% and 30 %% "
                         "of that type's messages): which values the fusion must check")
    for p in (scenarios, fuzz):
        p.add_argument("--seed", type=int, default=1)
        p.add_argument("--unfiltered", action="store_true",
                       help="every message to the fusion, as before the service bound one "
                            "autopilot (to measure what the binding and clock checks do)")
        p.add_argument("--json", action="store_true")
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
    return {"scenarios": _scenarios, "fuzz": _fuzz, "soak": _soak}[args.action](args)


HEADER = (f"{'scenario':24s} {'packets':>7s} {'crash':>5s} {'NaN':>4s} {'stale':>5s} "
          f"{'published':>11s} {'>3 sigma':>13s} {'worst m':>8s} {'sigmas':>7s} "
          f"{'resets':>6s} {'recovery s':>10s} {'reboots':>7s}")


def format_score(s: object) -> str:
    """One table row of a FaultScore."""
    recovery = "-" if s.recovery_s is None else f"{s.recovery_s:.2f}"
    return (f"{s.scenario:24s} {s.injected:7d} {s.crashes:5d} {s.nan_estimates:4d} "
            f"{s.stale:5d} {s.published:5d}/{s.published_clean:<5d} {s.beyond_3_sigma:5d} "
            f"({100 * s.beyond_share:4.1f}%) {s.worst_error_m:8.2f} {s.worst_sigmas:7.1f} "
            f"{s.resets:6d} {recovery:>10s} {s.reboots_seen:7d}")


def _print_scores(scores: list, as_json: bool) -> None:
    import dataclasses

    if as_json:
        print(json.dumps([dataclasses.asdict(s) | {"beyond_share": s.beyond_share}
                          for s in scores], default=float))
        return
    print(HEADER)
    for s in scores:
        print(format_score(s))


def _scenarios(args: argparse.Namespace) -> int:
    from sim import fusion_sim
    from sim.faults.scenarios import SCENARIOS, run_scenarios

    unknown = [n for n in args.names if n not in SCENARIOS]
    if unknown:
        raise InputError(f"unknown scenario '{unknown[0]}': one of {', '.join(SCENARIOS)}")
    _quiet()
    flight = fusion_sim.simulate(seed=args.seed)
    if not 0 <= args.window[0] < args.window[1]:
        raise InputError("--window FROM TO: 0 <= FROM < TO (seconds of the flight)")
    scores = run_scenarios(flight, args.names or list(SCENARIOS), args.seed,
                           tuple(args.window), filtered=not args.unfiltered)
    _print_scores(scores, args.json)
    return 0


def _fuzz(args: argparse.Namespace) -> int:
    from sim.faults.fuzz import fuzz_packets
    from sim.faults.scenarios import FUZZ_KINDS

    if args.packets <= 0:
        raise InputError("--packets must be positive")
    _quiet()
    if args.by_field:
        from sim import fusion_sim
        from sim.faults.scenarios import stream_fields

        scores = [fuzz_packets(args.packets, args.seed, filtered=not args.unfiltered,
                               progress=True, field=field)
                  for field in stream_fields(fusion_sim.simulate(seed=args.seed))]
    else:
        kinds = [(kind,) for kind in FUZZ_KINDS] if args.by_kind else [FUZZ_KINDS]
        scores = [fuzz_packets(args.packets, args.seed, filtered=not args.unfiltered,
                               progress=True, kinds=k) for k in kinds]
    _print_scores(scores, args.json)
    return 0


def _quiet() -> None:
    """The service's warnings (ignored sources, odd stamps) once per run would flood a
    table of hundreds of runs."""
    from daemon.run_command import setup_logging

    setup_logging("error")


def _soak(args: argparse.Namespace) -> int:
    from daemon.run_command import setup_logging
    from sim.faults.soak import soak
    from sim.render_command import parse_size
    from sim.synth.flight import synthetic_sequence

    if args.minutes <= 0:
        raise InputError("--minutes must be positive")
    setup_logging("warning")
    size = parse_size(args.size) if args.size else None
    sequence = synthetic_sequence(args.preset, size=size, seed=args.seed)
    result = soak(sequence, args.minutes, trace_from_min=args.tracemalloc_from)
    ten = result.rss_at(min(10.0, args.minutes))
    end = result.samples[-1][1] if result.samples else float("nan")
    first = result.peak(0.0, min(10.0, args.minutes))
    last = result.peak(max(0.0, args.minutes - 10.0), args.minutes)
    summary = {"preset": args.preset, "minutes": args.minutes, "rss_10min_mb": ten,
               "rss_end_mb": end, "growth_after_10min": end / ten - 1.0,
               "peak_first_10min_mb": first, "peak_last_10min_mb": last,
               "frames_offered": result.frames_offered, "frames_tracked": result.frames_tracked,
               "sent": result.sent, "exit_code": result.exit_code,
               "warnings": dict(result.warnings), "samples": result.samples}
    if args.json:
        print(json.dumps(summary))
        return result.exit_code
    print(f"soak {args.preset}{' ' + args.size if args.size else ''} {args.minutes:g} min: "
          f"RSS {ten:.0f} MB at 10 min (or the end of a shorter run), {end:.0f} MB at the end "
          f"({100 * (end / ten - 1):+.1f}%)")
    print(f"  highest RSS in the first 10 minutes {first:.0f} MB, in the last 10 {last:.0f} MB "
          f"({100 * (last / first - 1):+.1f}%)")
    print(f"  frames offered {result.frames_offered}, tracked {result.frames_tracked}, vision "
          f"messages sent {result.sent}, exit code {result.exit_code}")
    print("  warnings and errors logged: " + (", ".join(
        f"{name} {n}" for name, n in sorted(result.warnings.items())) or "none"))
    print("  RSS (MB) by minute: " + ", ".join(f"{m}: {r:.0f}" for m, r in result.per_minute()))
    for line in result.top_growth:
        print("  grew " + line)
    return result.exit_code
