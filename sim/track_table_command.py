"""`sdvl track-table`: run tracker configurations (the thesis' eight: patch/ORB matching x local
BA x outlier rejection) over sequences and print the table of ATE RMSE, frames tracked,
tracking ms and mapping ms (like thesis tables 7.1-7.4), with the original C++ SDVL figures
from the shared data README beside the real sequences. The other methods of
sim.track_methods (SDVL with depth `sdvl-depth`, the RGB-D baseline `rgbd-sift`) can be rows
too; their ATE is after an SE(3) alignment."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.track_methods import METHODS, SDVL_METHODS, alignment, check_method, load_config
from sim.track_sweep import Variant, format_summary, summary, variants

DEFAULT_SEQUENCES = ("vamr_ex01_checkerboard736", "kitti00_first200", "tum_fr1_rpy")
# the eight configurations of thesis 7.1 (Config1..Config8): matcher x local BA x outlier
# rejection, each a set of tracker parameters
CONFIGS = {
    f"{matcher}{'+ba' if ba else ''}{'+rej' if rej else ''}": {
        "matcher": matcher, "local_ba": ba, "outlier_rejection": rej}
    for matcher in ("patch", "orb") for ba in (False, True) for rej in (False, True)
}
THESIS_NAMES = {name: f"Config{i + 1}" for i, name in enumerate(CONFIGS)}
WARM_UP_FRAMES = 90
# tracker presets of the vo package used as the base config of sequences with this prefix
BASE_PRESETS = {"kitti": "kitti_10hz.toml"}
# original C++ SDVL (shared data README; ORB matching on, TUM preset): frames tracked, ATE RMSE
# m, tracking ms median
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
    parser.add_argument("--configs", default="all",
                        help="comma-separated configurations out of "
                             f"{', '.join(CONFIGS)} (or Config1..Config8 as in the thesis; "
                             "default: all eight), and other methods: "
                             f"{', '.join(m for m in METHODS if m != 'sdvl')}")
    parser.add_argument("--threaded", action="store_true", help="mapping in its own thread")
    parser.add_argument("--paced", action="store_true",
                        help="with --threaded: offer the frames at the camera rate (their "
                             "timestamps), so mapping and BA run between frames as in flight")
    parser.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="run the configurations N rounds per sequence and print each "
                             "round's tracking p95 relative to the first configuration, then "
                             "the median ratio (timing on a shared machine is noisy)")
    parser.add_argument("--seeds", default=None, metavar="LIST",
                        help="the tracker's random seeds ('0-9', '1,3'): every configuration "
                             "once per seed (default: the configuration's seed)")
    parser.add_argument("--world-seeds", default=None, metavar="LIST",
                        help="synthetic presets: fly each world seed ('0-2'; default 0)")
    parser.add_argument("--size", default=None, metavar="WxH",
                        help="synthetic presets at this image size (default: the preset's)")
    parser.add_argument("--textures", default=None, metavar="auto|procedural|DIR",
                        help="synthetic presets painted with these textures (as for sdvl "
                             "render; default auto)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE[,VALUE...]",
                        help="a tracker parameter on top of every configuration (repeatable); "
                             "several values make a variant per value, compared seed by seed "
                             "with the first in a summary at the end")
    parser.add_argument("--mapping-period", type=int, default=None, metavar="P",
                        help="emulated slow mapping, as for sdvl track")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N")
    parser.add_argument("--every", type=int, default=1, metavar="K",
                        help="every K-th frame only, as for sdvl track")
    parser.add_argument("--warm-up", type=int, default=WARM_UP_FRAMES, metavar="N",
                        help="first track N frames of the first sequence untimed, with every "
                             f"stage on, so numba's compilation is not timed (default "
                             f"{WARM_UP_FRAMES}; 0: none)")
    parser.add_argument("--json", action="store_true", help="one JSON object per row")


def run(args: argparse.Namespace) -> int:
    """Track every sequence with every configuration (and variant, and seed); print the table
    row by row, then the summary of a sweep. A run that fails is reported in its row and the
    table goes on (exit status 1 at the end)."""
    from sim.track_command import track_sequence
    from vo.config import TrackerConfig

    plan = _plan(args)
    if not args.json:
        print(header(), flush=True)
    rows: list[dict] = []
    first = True
    for seq_name, world, sequence in _sequences(args):
        if first and args.warm_up > 0:
            warm_up(sequence, track_sequence, TrackerConfig, args.warm_up)
        first = False
        ratios = []
        for round_ in range(1, args.repeat + 1):
            round_rows = []
            for name, variant, seed in plan:
                config = row_config(name, seq_name, variant, seed, TrackerConfig)
                row = table_run(seq_name, name, sequence, config, args, track_sequence)
                row.update(variant=variant.label, seed=seed, world_seed=world)
                round_rows.append(row)
                print(json.dumps(row) if args.json else format_row(row), flush=True)
            rows += round_rows
            if args.repeat > 1:
                ratios.append(p95_ratios(round_rows))
                print(format_ratios(seq_name, f"round {round_}", plan[0][0], ratios[-1],
                                    args.json), flush=True)
        if args.repeat > 1:
            print(format_ratios(seq_name, f"median of {args.repeat}", plan[0][0],
                                median_ratios(ratios), args.json), flush=True)
        if not args.json and seq_name in ORIGINAL and world is None:
            tracked, ate, ms = ORIGINAL[seq_name]
            print(f"{seq_name:<26} {'original C++ (ORB)':<22} {tracked:>9} {ate:>11} "
                  f"{'':>4} {ms:>9}", flush=True)
    _print_summary(rows, plan, args.json)
    return 1 if any("error" in r for r in rows) else 0


def _plan(args: argparse.Namespace) -> list[tuple[str, Variant, int | None]]:
    """(configuration, variant, tracker seed) of every run on a sequence, checking the
    options."""
    from sim.replay.seeds import parse_seeds

    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    if args.warm_up < 0:
        raise InputError("--warm-up must be 0 or more")
    if args.repeat <= 0:
        raise InputError("--repeat must be positive")
    if args.paced and not args.threaded:
        raise InputError("--paced needs --threaded (without a mapping thread nothing runs "
                         "between frames)")
    if args.mapping_period is not None and (args.threaded or args.mapping_period < 1):
        raise InputError("--mapping-period needs no --threaded and a period >= 1")
    seeds = [None] if args.seeds is None else parse_seeds(args.seeds)
    return [(name, variant, seed) for name in config_names(args.configs)
            for variant in variants(args.set) for seed in seeds]


def _sequences(args: argparse.Namespace):
    """(name, world seed or None, sequence in memory) of every sequence to track."""
    from sim.replay.seeds import parse_seeds
    from sim.sequence import every
    from sim.track_command import resolve_sequence

    size = None
    if args.size is not None:
        from sim.render_command import parse_size  # loads the renderer: only when asked

        size = parse_size(args.size)
    worlds = [None] if args.world_seeds is None else parse_seeds(args.world_seeds)
    depth = any(name in METHODS and alignment(name) == "se3"
                for name in config_names(args.configs))
    for name in args.sequences:
        for world in worlds:
            sequence = every(resolve_sequence(name, size, world, args.textures), args.every)
            yield Path(name).name, world, in_memory(sequence, args.max_frames,
                                                    depth and sequence.has_depth)


def _print_summary(rows: list[dict], plan: list, as_json: bool) -> None:
    """The sweep's summary (only when some configuration ran more than once on a sequence:
    several variants, seeds or world seeds)."""
    lines = summary(rows)
    if all(s["runs"] == 1 for s in lines) and len({v for _, v, _ in plan}) < 2:
        return
    first = plan[0][1].label
    for s in lines:
        print(json.dumps({"summary": s}) if as_json else format_summary(s, first), flush=True)


def row_config(name: str, seq_name: str, variant: Variant, seed: int | None, config_class):
    """The config of a row: a thesis configuration (or SDVL with depth, the first's
    parameters) over the sequence's base preset with the variant's parameters, or another
    method's defaults (a variant does not apply to those); `seed` (if given) replaces the
    config's."""
    if name in METHODS and name not in SDVL_METHODS:
        config = load_config(name, None)
        if seed is not None:
            config.seed = seed
        return config
    parameters = {**base_parameters(seq_name), **CONFIGS.get(name, {}),
                  **dict(variant.parameters)}
    if seed is not None:
        parameters["seed"] = seed
    return config_class.from_dict(parameters)


def table_run(seq_name: str, name: str, sequence, config, args: argparse.Namespace,
              track_sequence) -> dict:
    """One row: the sequence tracked with one configuration; a run that fails gives a row
    with its error (one broken run must not lose the rest of the table)."""
    method = {"method": name} if name in METHODS else {}
    try:
        if method:
            check_method(name, sequence)
        slow = None if args.mapping_period is None else (args.mapping_period, 0)
        report, _ = track_sequence(sequence, config, args.threaded, args.max_frames,
                                   quiet=True, paced=args.paced, slow_mapping=slow, **method)
    except Exception as exc:
        return {"sequence": seq_name, "config": name,
                "error": f"{type(exc).__name__}: {exc}"}
    return table_row(seq_name, name, report)


def p95_ratios(rows: list[dict]) -> dict[str, float | None]:
    """Each configuration's tracking p95 over the first row's (None where either is
    missing)."""
    base = rows[0].get("track_ms_p95")
    return {r["config"]: None if not base or r.get("track_ms_p95") is None
            else r["track_ms_p95"] / base for r in rows[1:]}


def median_ratios(rounds: list[dict[str, float | None]]) -> dict[str, float | None]:
    """Per configuration, the median of its rounds' ratios (None if it has none)."""
    out = {}
    for name in rounds[0]:
        values = [r[name] for r in rounds if r[name] is not None]
        out[name] = float(np.median(values)) if values else None
    return out


def format_ratios(sequence: str, label: str, first: str, ratios: dict[str, float | None],
                  as_json: bool) -> str:
    """A line of tracking p95 ratios to the first configuration (text or JSON)."""
    if as_json:
        return json.dumps({"sequence": sequence, "rounds": label, "p95_ratio_to": first,
                           "p95_ratio": ratios})
    text = ", ".join(f"{name} {'n/a' if r is None else format(r, '.3f')}"
                     for name, r in ratios.items())
    return f"{sequence:<26} {label}: track p95 / {first}'s: {text}"


def in_memory(sequence, max_frames: int | None, depth: bool = False):
    """The sequence with its frames read (or rendered) once and kept in memory, so every
    configuration replays the same images without decoding or rendering them again; with
    `depth`, its depth maps too (4 bytes a pixel), so that no depth map is read or rendered
    between two tracked frames either: a depth row's times are then comparable with a
    monocular row's."""
    frames = list(sequence.frames(max_frames))
    images = [image for _, image in frames]
    loaded = {}
    if depth:
        maps = [sequence.depth(i) for i in range(len(frames))]
        loaded = {"depth_loader": maps.__getitem__}
    return dataclasses.replace(sequence, timestamps=np.array([t for t, _ in frames]),
                               image_loader=images.__getitem__, frame_iter=None, **loaded)


def warm_up(sequence, track_sequence, config_class, frames: int) -> None:
    """Track the first frames with every stage on (patches, then ORB), untimed, so numba's
    compilation or cache loading is not counted in the first row's times."""
    for matcher in ("patch", "orb"):
        config = config_class(matcher=matcher, local_ba=True, outlier_rejection=True)
        track_sequence(sequence, config, False, frames, quiet=True)


def config_names(text: str) -> list[str]:
    """Configuration names from --configs ("all", names, or thesis ConfigN labels)."""
    by_thesis = {v.lower(): k for k, v in THESIS_NAMES.items()}
    names = []
    for item in (c.strip() for c in text.split(",")):
        if item == "all":
            names.extend(CONFIGS)
        elif item in METHODS and item != "sdvl":
            names.append(item)
        elif item in CONFIGS or item.lower() in by_thesis:
            names.append(by_thesis.get(item.lower(), item))
        elif item:
            raise InputError(f"unknown configuration {item} (known: all, "
                             f"{', '.join(CONFIGS)}, Config1..Config8, "
                             f"{', '.join(m for m in METHODS if m != 'sdvl')})")
    if not names:
        raise InputError("no configuration given")
    return list(dict.fromkeys(names))


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
    return {"sequence": sequence, "config": config, "thesis": THESIS_NAMES.get(config, "-"),
            "align": alignment(config) if config in METHODS else "sim3",
            "frames": report["frames"], "tracked": report["tracked"],
            "segments": report["segments"], "ate_rmse_m": report["ate_rmse_m"],
            "longest_segment_ate_rmse_m": report["longest_segment_ate_rmse_m"],
            "track_ms_median": report["track_ms_median"],
            "track_ms_p95": report["track_ms_p95"], "mapping_ms_median": stages.get("mapping"),
            "mapping_ms_mean": report["stages_mean"].get("mapping"),
            "path_length_m": report.get("path_length_m"),
            "first_pose_frame": report.get("first_pose_frame"),
            "relocalisations": report.get("relocalisations", 0),
            "reloc_max_added_rot_err_deg": report.get("reloc_max_added_rot_err_deg")}


def header() -> str:
    """Column titles of the text table."""
    return (f"{'sequence':<26} {'config':<22} {'tracked':>9} {'ATE m':>11} {'seg':>4} "
            f"{'track ms':>9} {'p95 ms':>7} {'map ms':>7} {'map mean':>8} {'ATE %path':>9} "
            f"{'1st pose':>8} {'reloc':>5} {'reloc deg':>9}")


def format_row(r: dict) -> str:
    """One line of the text table: ATE over all segments (several segments are only
    indicative, each having its own scale), tracking median and p95 ms, mapping median and
    mean ms, the ATE in % of the path's length, the index of the first frame with a pose,
    the relocalisations and the most orientation error one added (sim.track_relocs)."""
    thesis = THESIS_NAMES.get(r['config'], r.get('align', '').upper() + ' ATE')
    label = f"{r['config']} ({thesis})"
    extra = [f"world {r['world_seed']}" if r.get("world_seed") is not None else "",
             f"seed {r['seed']}" if r.get("seed") is not None else "",
             "" if r.get("variant", "as configured") == "as configured" else r["variant"]]
    label = " ".join([label, *filter(None, extra)])
    if "error" in r:
        return f"{r['sequence']:<26} {label:<22} failed: {r['error']}"

    def num(x, fmt):
        return format("n/a" if x is None else format(x, fmt), f">{fmt.split('.')[0]}")

    path = r.get("path_length_m")
    percent = None if not path or r["ate_rmse_m"] is None else 100.0 * r["ate_rmse_m"] / path
    return (f"{r['sequence']:<26} {label:<22} {r['tracked']:>4}/{r['frames']:<4} "
            f"{num(r['ate_rmse_m'], '11.4f')} {r['segments']:>4} "
            f"{num(r['track_ms_median'], '9.2f')} {num(r['track_ms_p95'], '7.2f')} "
            f"{num(r['mapping_ms_median'], '7.2f')} "
            f"{num(r['mapping_ms_mean'], '8.2f')} {num(percent, '9.2f')} "
            f"{num(r.get('first_pose_frame'), '8.0f')} {r.get('relocalisations', 0):>5} "
            f"{num(r.get('reloc_max_added_rot_err_deg'), '9.1f')}")
