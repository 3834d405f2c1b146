"""`sdvl ba-bench`: capture the local BA problems the mapping thread builds while sequences are
tracked (sequential mode, deterministic), solve each with every solver asked for (scipy's
least_squares methods, GTSAM), and print per solver the final cost, the time per problem
(median, p95) and whether the free keyframes moved toward the ground truth."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.ba_capture import Captured, capture, free_keyframe_errors, load, save

SOLVERS = ("trf", "dogbox", "lm", "gtsam")
CLOSER_M = 1e-4  # a keyframe moved toward the truth by more than this counts as closer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl ba-bench`."""
    parser.add_argument("sequences", nargs="*", default=["kitti00_first200", "survey-down"],
                        help="sequence folders, shared-data names or synthetic preset names "
                             "(default: kitti00_first200 survey-down)")
    parser.add_argument("--config", default="patch+ba+rej",
                        help="the track-table configuration tracked (local BA on; default "
                             "patch+ba+rej, over the sequence's preset as in track-table)")
    parser.add_argument("--seeds", default="0", metavar="LIST",
                        help="tracker seeds to capture with ('0-2'; default 0)")
    parser.add_argument("--world-seeds", default=None, metavar="LIST",
                        help="synthetic presets: the worlds to fly ('0-2'; default 0)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a tracker parameter for capture and solving (repeatable)")
    parser.add_argument("--solvers", default="trf,gtsam",
                        help=f"comma-separated, out of {', '.join(SOLVERS)} (default trf,gtsam)")
    parser.add_argument("--prior-scale", nargs="+", default=["1,1"], metavar="POSE,DEPTH",
                        help="multiply the captured problems' pose and depth prior weights "
                             "(0: without; default 1,1); several: each solver with each, to "
                             "see what the priors hold back")
    parser.add_argument("--all", action="store_true",
                        help="also the problems below ba_min_rms_px (the tracker skips them)")
    parser.add_argument("--save", type=Path, default=None, metavar="DIR",
                        help="pickle the captured problems there (one file per run)")
    parser.add_argument("--load", type=Path, default=None, metavar="PATH",
                        help="solve problems pickled by --save instead of tracking")
    parser.add_argument("--json", action="store_true", help="one JSON object per summary")


def run(args: argparse.Namespace) -> int:
    """Capture (or load) the problems, solve them with each solver, print the summaries."""
    from vo.config import TrackerConfig

    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    unknown = sorted(set(solvers) - set(SOLVERS))
    if unknown or not solvers:
        raise InputError(f"--solvers: unknown {', '.join(unknown) or '(none)'} (known: "
                         f"{', '.join(SOLVERS)})")
    if "gtsam" in solvers:
        from vo.ba_gtsam import import_gtsam

        import_gtsam()  # a missing library is said before minutes of tracking
    settings = _settings(args.set)
    config = TrackerConfig.from_dict(settings)
    captures = load(args.load) if args.load is not None else _capture_all(args, settings)
    scales = [_prior_scale(text) for text in args.prior_scale]
    captures = [c for c in captures if args.all or not c.gated]
    if not captures:
        raise InputError("no BA problem was captured (is local BA on and did tracking run?)")
    runs = [(solver, scale) for scale in scales for solver in solvers]
    labels = [solver if scale == (1.0, 1.0) else f"{solver} priors {scale[0]:g},{scale[1]:g}"
              for solver, scale in runs]
    rows = [solve_row(scaled_priors(c, *scale), solver, label, config) for c in captures
            for (solver, scale), label in zip(runs, labels, strict=True)]
    for line in summaries(rows, labels):
        print(json.dumps(line) if args.json else format_summary(line), flush=True)
    return 0


def _settings(items: list[str]) -> dict:
    """--set KEY=VALUE options as tracker parameters (one value each)."""
    from sim.track_sweep import variants

    found = variants(items)
    if len(found) != 1:
        raise InputError("ba-bench: --set takes one value per parameter")
    return dict(found[0].parameters)


def _prior_scale(text: str) -> tuple[float, float]:
    """--prior-scale POSE,DEPTH."""
    try:
        pose, depth = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--prior-scale takes two numbers POSE,DEPTH, not {text!r}") from None
    if min(pose, depth) < 0:
        raise InputError("--prior-scale: the factors must be 0 or more")
    return pose, depth


def scaled_priors(c: Captured, pose: float, depth: float) -> Captured:
    """c with its problem's pose prior square-root informations times `pose` and its depth
    prior weights times `depth` (0: without)."""
    p = c.problem
    if pose == 1.0 and depth == 1.0:
        return c
    U = None if p.pose_sqrt_info is None or pose == 0 else p.pose_sqrt_info * pose
    # a zero weight would leave a point free along its ray: a negligible one only fixes gauge
    w = p.prior_w * max(depth, 1e-6)
    return dataclasses.replace(c, problem=dataclasses.replace(p, pose_sqrt_info=U, prior_w=w))


def _capture_all(args: argparse.Namespace, settings: dict) -> list[Captured]:
    """Track every sequence (and world) with every tracker seed; capture the BA problems."""
    from sim.replay.seeds import parse_seeds
    from sim.track_command import resolve_sequence
    from sim.track_sweep import Variant
    from sim.track_table_command import config_names, row_config
    from vo.config import TrackerConfig

    name = config_names(args.config)[0]
    worlds = [None] if args.world_seeds is None else parse_seeds(args.world_seeds)
    out: list[Captured] = []
    for seq_name in args.sequences:
        for world in worlds:
            sequence = resolve_sequence(seq_name, seed=world)
            for seed in parse_seeds(args.seeds):
                config = row_config(name, Path(seq_name).name, Variant(tuple(settings.items())),
                                    seed, TrackerConfig)
                label = f"{Path(seq_name).name} w{world if world is not None else '-'} s{seed}"
                found = capture(sequence, config, label)
                if args.save is not None:
                    save(found, args.save / f"{label.replace(' ', '_')}.pkl")
                out += found
    return out


def solve_row(c: Captured, solver: str, label: str, config) -> dict:
    """One problem solved by one solver (a row labelled `label`): truncated cost before and
    after (ba.truncated_cost), observations kept, time, mean distance of the free keyframes
    from the truth before and after (None: no truth)."""
    from vo import bundle_adjustment as ba

    p = c.problem
    start = time.perf_counter()
    T, rho, keep = ba.solve(p, config.ba_first_iterations, config.ba_second_iterations, solver)
    seconds = time.perf_counter() - start
    before, after = free_keyframe_errors(c, p.T0), free_keyframe_errors(c, T)
    return {"sequence": c.label.split(" ")[0], "solver": label,
            "size": (p.n_free, len(p.slots) - p.n_free, len(p.points), len(p.obs_kf)),
            "cost0": ba.truncated_cost(p, p.T0, p.rho0), "cost": ba.truncated_cost(p, T, rho),
            "kept": float(keep.mean()), "ms": 1000.0 * seconds,
            "err_before": None if before is None else float(before.mean()),
            "err_after": None if after is None else float(after.mean())}


def summaries(rows: list[dict], solvers: list[str]) -> list[dict]:
    """Per sequence and solver: problems, their median size (free and fixed keyframes, points,
    observations), median final/start truncated cost, median cost over the
    first solver's on the same problem, observations kept, ms median and p95, free keyframes'
    median error before and after, and on how many problems they moved closer / away."""
    out = []
    for seq in dict.fromkeys(r["sequence"] for r in rows):
        by = {s: [r for r in rows if r["sequence"] == seq and r["solver"] == s] for s in solvers}
        first = np.array([r["cost"] for r in by[solvers[0]]])
        for solver, mine in by.items():
            cost = np.array([r["cost"] for r in mine])
            ms = np.array([r["ms"] for r in mine])
            truth = [(r["err_before"], r["err_after"]) for r in mine if r["err_before"] is not None]
            b, a = (np.array(v) for v in zip(*truth, strict=True)) if truth else ([], [])
            out.append({
                "sequence": seq, "solver": solver, "problems": len(mine),
                "size_median": [float(v) for v in np.median([r["size"] for r in mine], axis=0)],
                "cost_ratio": float(np.median(cost / np.array([r["cost0"] for r in mine]))),
                "cost_vs_first": float(np.median(cost / np.maximum(first, 1e-12))),
                "kept": float(np.mean([r["kept"] for r in mine])),
                "ms_median": float(np.median(ms)), "ms_p95": float(np.percentile(ms, 95)),
                "with_truth": len(truth),
                "err_before_m": float(np.median(b)) if truth else None,
                "err_after_m": float(np.median(a)) if truth else None,
                "closer": int(np.sum(np.asarray(a) < np.asarray(b) - CLOSER_M)),
                "farther": int(np.sum(np.asarray(a) > np.asarray(b) + CLOSER_M))})
    return out


def format_summary(s: dict) -> str:
    """One line of the text summary."""
    truth = ("no ground truth" if not s["with_truth"] else
             f"free kf error median {s['err_before_m']:.4f} -> {s['err_after_m']:.4f} m, "
             f"closer on {s['closer']}, farther on {s['farther']} of {s['with_truth']}")
    free, fixed, points, obs = s["size_median"]
    return (f"{s['sequence']:<18} {s['solver']:<20} {s['problems']:>4} problems (median "
            f"{free:g} free + {fixed:g} fixed keyframes, {points:g} points, {obs:g} obs)  cost "
            f"x{s['cost_ratio']:.3f} of start, x{s['cost_vs_first']:.3f} of first solver's  "
            f"kept {100 * s['kept']:.1f}%  ms median {s['ms_median']:.1f} p95 "
            f"{s['ms_p95']:.1f}  {truth}")
