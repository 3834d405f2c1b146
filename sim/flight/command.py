"""`sdvl fly [MISSION]`: the simulated ArduCopter flies a mission on our estimate, with the
camera rendered where it truly is, and the report says whether a real one would be ready.

By default on a virtual clock (deterministic, sim/flight/loop.py); `--realtime` runs the real
service against the simulated autopilot in its own process on the wall clock
(sim/flight/realtime.py), for the latency on this machine.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from daemon.config import Config, load_config, replace
from daemon.run_command import setup_logging
from sdvl.errors import InputError
from sim.autopilot.barometer import BaroSpec
from sim.autopilot.imu import ImuSpec
from sim.flight.flight_run import FlightRun, Timing
from sim.flight.frames_csv import write_flight_frames
from sim.flight.loop import ClosedLoop
from sim.flight.mission import DEFAULT_MISSION, Mission, load_mission
from sim.flight.report import flight_report, format_flight
from sim.flight.runner import step_printer
from sim.flight.scores import score
from sim.flight.seeds import format_seed_table, summarize_flights
from sim.render_command import parse_size
from sim.replay.flight import SENSOR_STREAMS
from sim.replay.seeds import parse_seeds

DEFAULT_SIZE = "320x240"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl fly`."""
    parser.add_argument("mission", nargs="?", default=DEFAULT_MISSION,
                        help="mission file (TOML, format: sim/flight/mission.py) or the name of "
                             "a built-in one: default (take off to 3 m, LOITER 30 s, GUIDED 2 m "
                             "square, land), survey, short")
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, default=0,
                       help="world seed (its textures and layout, the autopilot's sensor "
                            "noise); default 0")
    seeds.add_argument("--seeds", default=None, metavar="LIST",
                       help="fly once per seed ('0-19', '1,3,7'): a line per seed and the "
                            "worst over them")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="with --seeds: fly N seeds at once in their own processes (the "
                             "virtual clock makes the table the same; default 1)")
    parser.add_argument("--without", action="append", default=[], choices=sorted(SENSOR_STREAMS),
                        help="the autopilot does not stream this sensor to us (repeatable)")
    parser.add_argument("--baro-ground-effect", type=float, default=None, metavar="M",
                        help="how low the simulated barometer reads at the ground under hover "
                             f"thrust (metres; default {BaroSpec().ground_effect_m:g}, ArduPilot "
                             "SITL's autotest; flown airframes 0.4 to 11)")
    parser.add_argument("--vibration-spread", type=float, default=None, metavar="S",
                        help="each motor's vibration frequency off the hover one by a seeded "
                             "N(0, S) share (default 0: all four at 400 Hz / 5, a tone the IMU "
                             "streams fold into a steady offset; motors and props differ)")
    parser.add_argument("--depth", action="store_true",
                        help="RGB-D: the world's depth camera (the preset's sensor model, "
                             "sim/synth/depth_sensor.py) feeds the service (camera.depth)")
    parser.add_argument("--size", default=DEFAULT_SIZE, metavar="WxH",
                        help=f"camera image size (default {DEFAULT_SIZE})")
    parser.add_argument("--latency-ms", type=float, default=None, metavar="MS",
                        help="capture-to-send latency of the companion in the virtual-clock "
                             f"loop (default {1e3 * Timing().capture_to_send_s:g})")
    parser.add_argument("--drop-frames", type=float, default=0.0, metavar="SHARE",
                        help="the virtual-clock service drops this share of the frames in "
                             "seeded runs of 3 on average, as a busy machine's does (default 0; "
                             "--realtime --load measures a real one)")
    parser.add_argument("--config", type=Path, default=None,
                        help="service config (TOML, as for sdvl run); its link and camera are "
                             "the simulation's, its mounting the world's")
    parser.add_argument("--realtime", action="store_true",
                        help="the real service on the wall clock against the simulated "
                             "autopilot in its own process (measures this machine's latency)")
    parser.add_argument("--load", type=int, default=0, metavar="N",
                        help="with --realtime: N busy processes beside it (a loaded machine)")
    parser.add_argument("--plot", type=Path, default=None, metavar="OUT.png",
                        help="planned and flown path, the autopilot's estimate and ours")
    parser.add_argument("--frames-csv", type=Path, default=None, metavar="FILE",
                        help="one flight on the virtual clock: a row per frame (the tracker's "
                             "counts and map pose, our estimate and its std, the truth; "
                             "sim/flight/frames_csv.py)")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object (keys: sim/flight/report.py KEYS)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress lines on stderr")
    parser.add_argument("--log-level", default="warning",
                        choices=("debug", "info", "warning", "error"),
                        help="log level of the service's parts on stderr (default warning)")


def fly(mission: Mission, config: Config, seed: int, args: argparse.Namespace) -> FlightRun:
    """One flight of `mission` as the arguments say."""
    size = parse_size(args.size)
    without = tuple(args.without)
    prefix = None if args.quiet else f"fly {mission.name} seed {seed}"
    if args.realtime:
        from sim.flight.realtime import fly_realtime

        return fly_realtime(mission, config, seed, size, without, args.load, prefix)
    latency_s = Timing().capture_to_send_s if args.latency_ms is None else args.latency_ms / 1e3
    timing = Timing(capture_to_send_s=latency_s, drop_share=args.drop_frames)
    baro = (None if args.baro_ground_effect is None
            else BaroSpec(ground_effect_m=args.baro_ground_effect))
    imu = (None if args.vibration_spread is None
           else ImuSpec(motor_hz_spread=args.vibration_spread))
    return ClosedLoop(mission, config, seed, size, without, timing,
                      on_step=prefix and step_printer(prefix), baro=baro, imu=imu).run()


def run(args: argparse.Namespace) -> int:
    """Fly, report, plot."""
    if args.jobs < 1 or (args.jobs > 1 and args.realtime):
        raise InputError("--jobs N flies N virtual-clock flights at once (N >= 1); a --realtime "
                         "flight measures the machine, so it flies alone")
    if args.baro_ground_effect is not None and (args.realtime or args.baro_ground_effect < 0):
        raise InputError("--baro-ground-effect is the virtual-clock loop's barometer (>= 0 m)")
    if args.vibration_spread is not None and (args.realtime
                                              or not 0.0 <= args.vibration_spread <= 0.3):
        raise InputError("--vibration-spread is the virtual-clock loop's IMU (0 to 0.3)")
    if args.load and not args.realtime:
        raise InputError("--load loads the machine for a --realtime flight; add --realtime")
    if args.latency_ms is not None and (args.realtime or args.latency_ms < 0):
        raise InputError("--latency-ms is the virtual-clock loop's latency (>= 0); --realtime "
                         "measures its own")
    if args.drop_frames and (args.realtime or not 0.0 <= args.drop_frames <= 0.6):
        raise InputError("--drop-frames is the virtual-clock loop's share of dropped frames "
                         "(0 to 0.6); --realtime drops what the machine makes it drop")
    if args.frames_csv is not None and (args.seeds is not None or args.realtime):
        raise InputError("--frames-csv writes one virtual-clock flight: use --seed N, "
                         "without --realtime")
    mission = load_mission(args.mission)
    config = load_config(args.config) if args.config else Config()
    if args.depth:
        config = replace(config, camera={"depth": True})
    setup_logging(args.log_level)
    if args.seeds is not None:
        if args.plot is not None:
            raise InputError("--plot draws one flight: use --seed N with it, not --seeds")
        return _seeds(mission, config, parse_seeds(args.seeds), args)
    flight = fly(mission, config, args.seed, args)
    report = flight_report(flight, score(flight))
    if args.plot is not None:
        from sim.flight.plot import plot_flight

        plot_flight(flight, args.plot, f"sdvl fly {mission.name}, seed {args.seed}")
    if args.frames_csv is not None:
        write_flight_frames(args.frames_csv, flight)
    print(json.dumps(report) if args.json else format_flight(report, len(mission.steps)))
    return 0


def fly_report(mission: Mission, config: Config, seed: int, args: argparse.Namespace) -> dict:
    """The report of one flight (a worker process's job with --jobs)."""
    setup_logging(args.log_level)
    flight = fly(mission, config, seed, args)
    return flight_report(flight, score(flight))


def _seeds(mission: Mission, config: Config, seeds: list[int],
           args: argparse.Namespace) -> int:
    if args.jobs > 1 and not args.realtime:
        from concurrent.futures import ProcessPoolExecutor

        # a fresh process per flight: a forked worker's later flights differed from the same
        # flights alone (seed 10: LOITER 0.25 m in a 20-seed pool, 0.71 m alone or in sequence)
        with ProcessPoolExecutor(min(args.jobs, len(seeds)), max_tasks_per_child=1) as pool:
            n = len(seeds)
            reports = list(pool.map(fly_report, [mission] * n, [config] * n, seeds, [args] * n))
    else:
        reports = [fly_report(mission, config, seed, args) for seed in seeds]
    summary = summarize_flights(reports)
    if args.json:
        print(json.dumps({"seeds": seeds, "runs": reports, "summary": summary}))
    else:
        print(format_seed_table(seeds, reports, summary))
    return 0
