"""`sdvl replay [SEQUENCE_OR_PRESET]`: a sequence through the whole service against a simulated
autopilot, scored on what the autopilot received.

Without an argument it flies the synthetic downward preset DEFAULT_PRESET, rendered on the fly.
The received poses and the ground truth they are scored against are written as TUM files into
the output folder, so `sdvl eval GROUNDTRUTH RECEIVED` reproduces the ATE.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from daemon.config import Config, load_config, replace
from daemon.run_command import setup_logging
from sdvl.errors import InputError
from sim.replay.flight import SENSOR_STREAMS, is_ned
from sim.replay.harness import choose_estimator, during_replay, run_replay
from sim.replay.report import build_report, format_report
from sim.replay.seeds import format_seeds, parse_seeds, summarize

DEFAULT_PRESET = "hover-down"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl replay`."""
    parser.add_argument("sequence", nargs="?", default=DEFAULT_PRESET,
                        help="sequence folder, video, name of a folder in the shared data "
                             f"($SDVL_DATA) or synthetic preset (default: {DEFAULT_PRESET})")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--realtime", dest="realtime", action="store_const", const=True,
                      help="play frames at their timestamps; tracking that falls behind drops "
                           "frames (default with fusion)")
    mode.add_argument("--fast", dest="realtime", action="store_const", const=False,
                      help="play frames as fast as tracking takes them (at most at "
                           "mavlink.max_rate_hz, so every estimate is sent), none dropped "
                           "(default with pass-through); with fusion: lockstep on a virtual "
                           "clock with the flight's recorded sensors, deterministic (no link)")
    parser.add_argument("--estimator", choices=("auto", "fusion", "pass-through"),
                        default="auto",
                        help="auto (default): the config's [fusion] choice for sequences that "
                             "know where down is (synthetic flights), pass-through for "
                             "hand-held datasets")
    parser.add_argument("--config", type=Path, default=None,
                        help="service config (TOML, as for sdvl run); its link and camera "
                             "source are replaced by the replay's, its mounting and default "
                             "sensor noise by a synthetic flight's own")
    parser.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                        help="the simulated autopilot (default ardupilot), set up as "
                             "sdvl check-autopilot --apply leaves it (sim/autopilot/BEHAVIOUR.md)")
    parser.add_argument("--without", action="append", default=[],
                        choices=sorted(SENSOR_STREAMS),
                        help="the autopilot does not stream this sensor (repeatable): fusion "
                             "with fewer sensors")
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, default=None,
                       help="seed of a synthetic preset (its world, sensor noise; default 0)")
    seeds.add_argument("--seeds", default=None, metavar="LIST",
                       help="fly a synthetic preset once per seed ('0-4', '1,3,7') and print a "
                            "line per seed and the average NEES over the runs (ANEES): the "
                            "filter's consistency is judged over flights (sim/replay/seeds.py)")
    parser.add_argument("--depth", action="store_true",
                        help="the sequence's depth maps go to the service with its frames, as "
                             "from a depth camera (camera.depth): metric poses from the first "
                             "frame (synthetic presets, sequences with a depth.txt)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N",
                        help="replay only the first N frames")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="folder for received.txt and groundtruth.txt (TUM; default "
                             "sdvl-replay/NAME)")
    parser.add_argument("--plot", type=Path, default=None, metavar="OUT.png",
                        help="write a PNG: top view, height and position error over time")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (keys: sim/replay/report.py KEYS)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--log-level", default="warning",
                        choices=("debug", "info", "warning", "error"),
                        help="service log level on stderr (default warning)")


def _open(name: str, seed: int | None) -> object:
    """The sequence named on the command line; a synthetic preset with `seed`."""
    from sim.track_command import resolve_sequence

    if seed is None:
        return resolve_sequence(name)
    from sim.synth.presets import PRESETS

    if name not in PRESETS or Path(name).exists():
        raise InputError(f"--seed is for synthetic presets ({', '.join(PRESETS)}), not "
                         f"'{name}'")
    from sim.synth.flight import synthetic_sequence

    return synthetic_sequence(name, seed=seed)


def run(args: argparse.Namespace) -> int:
    """Replay, report, plot."""
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    config = load_config(args.config) if args.config else Config()
    setup_logging(args.log_level)
    if args.seeds is not None:
        return _run_seeds(args, config)
    sequence = _open(args.sequence, args.seed)
    replay, report, aligned, reference = _replay(sequence, config, args,
                                                 args.out or Path("sdvl-replay") / sequence.name)
    if args.plot is not None:
        if aligned is None:
            raise InputError("no plot: the sequence has no ground truth or too few poses "
                             "were received")
        from sim.plots import plot_replay

        plot_replay(aligned, during_replay(reference, replay), args.plot,
                    f"sdvl replay {sequence.name}: {report['mode']}, {report['estimator']}",
                    ned=is_ned(sequence))
    print(json.dumps(report) if args.json else format_report(report))
    return replay.exit_code


def _replay(sequence, config: Config, args: argparse.Namespace, out_dir: Path):
    """One replay of `sequence`: the run, its report, the aligned trajectories and reference."""
    config = choose_estimator(config, sequence, args.estimator)
    if args.depth:
        config = replace(config, camera={"depth": True})
    realtime = config.fusion.enabled if args.realtime is None else args.realtime
    replay = run_replay(sequence, config, realtime, args.max_frames, progress=not args.quiet,
                        without=tuple(args.without), autopilot=args.autopilot)
    return (replay, *build_report(replay, out_dir))


def _run_seeds(args: argparse.Namespace, config: Config) -> int:
    """The preset once per seed of --seeds; a line per seed and the summary over them."""
    if args.plot is not None:
        raise InputError("--plot draws one run: use --seed N with it, not --seeds")
    seeds = parse_seeds(args.seeds)
    reports, exit_code = [], 0
    for seed in seeds:
        sequence = _open(args.sequence, seed)
        out_dir = (args.out or Path("sdvl-replay") / sequence.name) / f"seed{seed}"
        replay, report, _, _ = _replay(sequence, config, args, out_dir)
        reports.append(report)
        exit_code = exit_code or replay.exit_code
    summary = summarize(reports)
    if args.json:
        print(json.dumps({"seeds": seeds, "runs": reports, "summary": summary}))
    else:
        print(format_seeds(seeds, reports, summary))
    return exit_code
