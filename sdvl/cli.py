"""The `sdvl` command: one entry point, a subcommand per tool.

Each subcommand lives in the package that owns it, in a module with `add_arguments(parser)` and
`run(args) -> int`; it is imported only when chosen, so `sdvl --help` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from sdvl.errors import InputError

EXIT_USER_ERROR = 2

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("daemon.run_command", "the companion service: camera -> tracker -> MAVLink"),
    "check-autopilot": ("daemon.check_autopilot_command", "check autopilot parameters for vision"),
    "mount-test": ("daemon.mount_test_command", "bench check of the camera mounting: move by hand"),
    "fusion-sim": ("sim.fusion_sim_command", "fusion EKF on a simulated flight: accuracy, NEES"),
    "bench-latency": ("sim.bench_latency_command", "capture-to-send latency vs tracking time"),
    "replay": ("sim.replay.command", "the service on a sequence against a simulated autopilot"),
    "fly": ("sim.flight.command", "closed loop: a simulated ArduCopter flies a mission on us"),
    "render": ("sim.render_command", "render a synthetic flight: images, ground truth, IMU"),
    "eval": ("sim.eval_command", "score an estimated trajectory against ground truth (ATE, RPE)"),
    "track": ("sim.track_command", "run the SDVL tracker over a sequence: accuracy and timing"),
    "track-table": ("sim.track_table_command", "tracker configurations x sequences: ATE, timing"),
    "track-compare": ("sim.track_compare_command",
                      "this tracker timed side by side with a git revision's: stage ratios"),
    "ba-bench": ("sim.ba_bench_command", "local BA solvers on captured problems: cost, time"),
    "map": ("sim.map_command", "fuse depth along metric poses into a 3D occupancy map"),
    "calibrate": ("calib.calibrate_command", "calibrate a camera; convert calibration files"),
    "results": ("sdvl.results", "regenerate the measurements in RESULTS.md from their commands"),
    "faults": ("sim.faults.command", "fault injection and fuzzing of the service; memory soak"),
}


def build_parser(argv: list[str]) -> tuple[argparse.ArgumentParser, object | None]:
    """The top-level parser, with the chosen subcommand's module loaded and its arguments added."""
    parser = argparse.ArgumentParser(
        prog="sdvl", description="SDVL Companion: monocular visual localisation for drones."
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = next((a for a in argv if not a.startswith("-")), None)
    module = None
    for name, (module_name, help_text) in COMMANDS.items():
        cmd_parser = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            module = importlib.import_module(module_name)
            module.add_arguments(cmd_parser)
    return parser, module


def main(argv: list[str] | None = None) -> int:
    """Run `sdvl` with `argv`; returns the process exit code."""
    argv = sys.argv[1:] if argv is None else argv
    parser, module = build_parser(argv)
    args = parser.parse_args(argv)
    if module is None:
        parser.print_help()
        return EXIT_USER_ERROR
    try:
        return int(module.run(args) or 0)
    except InputError as exc:
        print(f"sdvl {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(f"sdvl {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
