"""`sdvl track SEQUENCE`: run the SDVL tracker over a sequence offline, with accuracy and per-stage
timing (median, p95) at the end; doubles as the tracker benchmark."""

from __future__ import annotations

import argparse
import csv
import json
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.replay.progress import progress_bar
from sim.sequence import every
from sim.shared_data import shared_data_dir
from sim.track_methods import METHODS, alignment, build_tracker, check_method, load_config
from sim.track_relocs import add_relocalisations, format_relocalisations
from sim.trajectory import Trajectory, write_tum
from vo.result import Quality

FRAME_COLUMNS = ("t", "quality", "matches", "attempts", "ransac_hypotheses", "inliers",
                 "keyframe", "new_segment", "relocalized", "merged", "held", "error_m")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl track`."""
    parser.add_argument("sequence", help="sequence folder, video, or the name of a folder in the "
                                         "shared data ($SDVL_DATA)")
    parser.add_argument("--out", type=Path, default=None, help="write the trajectory (TUM)")
    parser.add_argument("--config", type=Path, default=None,
                        help="TOML file with tracker parameters (top level or [tracker])")
    parser.add_argument("--threaded", action="store_true",
                        help="mapping in its own thread (default: one mapping step per frame)")
    parser.add_argument("--mapping-period", type=int, default=None, metavar="P",
                        help="emulate a slow mapping thread, deterministically: each frame's "
                             "mapping step takes P frame periods (frames that come while the "
                             "mapping backlog is full are skipped)")
    parser.add_argument("--mapping-delay", type=int, default=0, metavar="D",
                        help="with --mapping-period: a mapping step starts D frame periods "
                             "after its frame at the earliest")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N")
    parser.add_argument("--every", type=int, default=1, metavar="K",
                        help="track every K-th frame only: K times the motion between frames, "
                             "as a slower camera or a faster vehicle would see (default 1)")
    parser.add_argument("--size", default=None, metavar="WxH",
                        help="image size for a synthetic preset (default: the preset's)")
    parser.add_argument("--memory", type=int, default=None, metavar="N",
                        help="every N frames record resident memory and the map's size "
                             "(keyframes, points, observations); report the peak RSS")
    parser.add_argument("--frames-csv", type=Path, default=None, metavar="FILE",
                        help="write one CSV row per frame: time, quality, matches, match "
                             "attempts, RANSAC hypotheses, inliers, keyframe, new-segment, "
                             "relocalised and merged flags, position error (m) after the Sim(3) "
                             "alignment")
    parser.add_argument("--method", default="sdvl", choices=list(METHODS),
                        help="sdvl (monocular, ATE after Sim(3) alignment), sdvl-depth (SDVL "
                             "with the sequence's depth maps: metric, SE(3) alignment) or "
                             "rgbd-sift (the RGB-D odometry baseline, needs depth; SE(3) "
                             "alignment)")
    parser.add_argument("--profile", type=int, default=None, metavar="N",
                        help="profile the tracker's calls (cProfile) and list the N functions "
                             "with the most own time per frame, and Python calls per frame")
    parser.add_argument("--json", action="store_true", help="print one JSON object at the end")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")


def resolve_sequence(name: str, size: tuple[int, int] | None = None, seed: int | None = None,
                     textures: str | None = None):
    """Open a sequence by path, or by name inside the shared data folder; `size` renders a
    synthetic preset at another image size, `seed` flies another of its worlds, `textures`
    ('auto', 'procedural' or a folder, as for sdvl render) paints it."""
    from sim.datasets import open_sequence

    if size is not None or seed is not None or textures is not None:
        from sim.synth.flight import synthetic_sequence
        from sim.synth.presets import PRESETS

        if name not in PRESETS:
            given = [option for option, value in (("--size", size), ("--world-seeds", seed),
                                                  ("--textures", textures)) if value is not None]
            raise InputError(f"{' and '.join(given)} {'is' if len(given) == 1 else 'are'} for "
                             f"synthetic presets ({', '.join(PRESETS)}), not {name}")
        return synthetic_sequence(name, size=size, seed=seed or 0, textures=textures or "auto")
    path = Path(name)
    if not path.exists():
        data = shared_data_dir()
        if (data / name).exists():
            path = data / name
    return open_sequence(path)


def stage_stats(timings: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per stage: median, p95 and mean in ms over the frames that ran it."""
    names = sorted({k for t in timings for k in t})
    out = {}
    for name in names:
        values = np.array([t[name] for t in timings if name in t])
        out[name] = {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)),
                     "mean": float(np.mean(values)), "n": len(values)}
    return out


def run(args: argparse.Namespace) -> int:
    """Track the sequence and report."""
    if args.max_frames is not None and args.max_frames <= 0:
        raise InputError("--max-frames must be positive")
    if args.memory is not None and args.memory <= 0:
        raise InputError("--memory must be positive")
    if args.profile is not None and (args.profile <= 0 or args.threaded):
        raise InputError("--profile needs a positive count and no --threaded (cProfile sees "
                         "one thread: mapping must run in the tracking thread)")
    slow = None
    if args.mapping_period is not None:
        if args.threaded or args.mapping_period < 1 or args.mapping_delay < 0:
            raise InputError("--mapping-period needs no --threaded, a period >= 1 and a "
                             "delay >= 0")
        slow = (args.mapping_period, args.mapping_delay)
    config = load_config(args.method, args.config)
    size = None
    if args.size is not None:
        from sim.render_command import parse_size  # loads the renderer: only when asked

        size = parse_size(args.size)
    sequence = every(resolve_sequence(args.sequence, size), args.every)
    check_method(args.method, sequence)
    if args.memory is not None and args.method == "rgbd-sift":
        raise InputError("--memory reports SDVL's map: it is for --method sdvl or sdvl-depth")
    rows: list[dict] | None = None if args.frames_csv is None else []
    report, estimate = track_sequence(sequence, config, args.threaded, args.max_frames,
                                      args.quiet, args.memory, frame_rows=rows,
                                      slow_mapping=slow, method=args.method,
                                      profile_top=args.profile)
    if args.out is not None and estimate is not None:
        write_tum(estimate, args.out)
    if rows is not None:
        write_frames_csv(args.frames_csv, rows, sequence.groundtruth, estimate,
                         alignment(args.method))
    print(json.dumps(report) if args.json else format_report(report))
    return 0


def track_sequence(sequence, config, threaded: bool, max_frames: int | None,
                   quiet: bool, memory_every: int | None = None,
                   paced: bool = False, frame_rows: list[dict] | None = None,
                   slow_mapping: tuple[int, int] | None = None, method: str = "sdvl",
                   profile_top: int | None = None) -> tuple[dict, Trajectory | None]:
    """Run the tracker over a sequence: the report (see build_report) and the trajectory;
    with `memory_every`, the report has "memory" samples and "peak_rss_mb"; `paced` offers
    each frame no earlier than its timestamp after the first (the camera's rate, so a mapping
    thread works in the gaps as in flight) instead of as fast as tracking goes; `frame_rows`
    gets one frame_row per frame tracked; `slow_mapping` (period, delay) emulates a slow
    mapping thread (sim.slow_mapping), and the report counts the frames it "skipped";
    `method` picks the tracker (sim.track_methods); `profile_top` profiles the tracker's calls
    and puts that many functions in the report's "profile" (sim.track_profile)."""
    from sim.slow_mapping import SlowMapping
    from sim.track_profile import FrameProfiler

    tracker = build_tracker(method, sequence, config, threaded, slow_mapping is not None)
    offer = tracker.process if slow_mapping is None else SlowMapping(tracker,
                                                                     *slow_mapping).offer
    profiler = FrameProfiler() if profile_top else None
    if profiler is not None:
        offer = profiler.wrap(offer)
    log = TrackLog(frame_rows)
    pace = camera_rate() if paced else lambda t: None
    bar = progress_bar("track", min(max_frames or len(sequence), len(sequence)), enabled=not quiet)
    try:
        for t, image in sequence.frames(max_frames):
            pace(t)
            result = offer(image, t)
            log.add(t, result)
            if result is None:
                continue
            if memory_every and log.n_frames % memory_every == 0:
                log.memory.append(memory_sample(tracker, log.n_frames))
            bar.set_postfix(tracked=len(log.poses), quality=result.quality, refresh=False)
            bar.update()
    finally:
        tracker.close()
        bar.close()
    estimate = (Trajectory.from_matrices(np.array(log.times), np.array(log.poses))
                if log.poses else None)
    report = build_report(sequence, log.n_frames, estimate, np.array(log.segment), log.timings,
                          log.qualities, log.first_pose_s, alignment(method))
    add_relocalisations(report, sequence.groundtruth, estimate, np.array(log.segment),
                        np.array(log.relocalised, dtype=int))
    report["skipped"] = log.skipped
    report["tracked_late"] = log.late
    report["merges"] = log.merges
    report["first_pose_frame"] = log.first_pose_frame
    if alignment(method) == "se3":  # a depth method: its map starts on the first depth map
        report["first_depth_frame"] = tracker.first_depth_frame
    # local BAs the mapping thread skipped or ended early for a waiting frame (current map)
    mapper = getattr(tracker, "mapper", None)
    report["ba_skipped"] = getattr(mapper, "skipped_ba", 0)
    report["ba_shortened"] = getattr(mapper, "shortened_ba", 0)
    if profiler is not None:
        report["profile"] = profiler.rows(profile_top)
    if memory_every:
        add_memory(report, log.memory)
    return report, estimate


def add_memory(report: dict, samples: list[dict]) -> None:
    """Put the memory samples and the peak resident memory (MB) into a report."""
    report["memory"] = samples
    # Linux updates ru_maxrss lazily: a sample taken since may be higher
    report["peak_rss_mb"] = max([resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0]
                                + [m["rss_mb"] for m in samples])


@dataclass
class TrackLog:
    """What track_sequence collects from the frames' results."""

    frame_rows: list[dict] | None = None  # frame_row of each frame tracked, when given
    started: float = field(default_factory=time.perf_counter)
    n_frames: int = 0
    skipped: int = 0  # frames a slow mapping thread made the tracker skip
    times: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    segment: list[int] = field(default_factory=list)  # map segment of each pose
    relocalised: list[int] = field(default_factory=list)  # indices of relocalised poses
    timings: list[dict[str, float]] = field(default_factory=list)
    qualities: list[str] = field(default_factory=list)
    memory: list[dict] = field(default_factory=list)
    first_pose_s: float | None = None  # seconds from the start to the first pose (not late)
    first_pose_frame: int | None = None  # index of the first frame with a pose of its own
    late: int = 0  # poses given late (FrameResult.earlier), among `poses`
    merges: int = 0  # maps joined to the next one (FrameResult.merged)

    def add(self, t: float, result) -> None:
        """One camera frame at time t: its FrameResult, or None when it was skipped."""
        self.n_frames += 1
        if result is None:
            self.skipped += 1
            return
        self.qualities.append(result.quality)
        if self.frame_rows is not None:
            self.frame_rows.append(frame_row(result))
        if result.quality != Quality.INITIALIZING:
            self.timings.append(result.timings)
        if getattr(result, "merged", None) is not None:  # of the maps before this result's
            self._merge(result.merged)
        earlier = getattr(result, "earlier", [])
        for late in earlier:  # the frames a new map's initialiser waited through
            self._add_pose(late.t, late.T_w_c, late.new_segment, False)
        self.late += len(earlier)
        if result.has_pose:
            starts = result.new_segment and not (earlier and earlier[0].new_segment)
            self._add_pose(t, result.T_w_c, starts, getattr(result, "relocalized", False))
            if self.first_pose_s is None:
                self.first_pose_s = time.perf_counter() - self.started
                self.first_pose_frame = self.n_frames - 1

    def _merge(self, S) -> None:
        """The map before the newest re-initialisation was joined to the current one: its
        poses, moved into the current map's world by S (vo.map_merge.Similarity), join its
        segment."""
        if not self.segment or self.segment[-1] == 0:
            return
        current = self.segment[-1]
        for k, seg in enumerate(self.segment):
            if seg == current - 1:
                self.poses[k] = S.pose(self.poses[k])
            elif seg == current:
                self.segment[k] = current - 1
        self.merges += 1

    def _add_pose(self, t: float, T_w_c: np.ndarray, new_segment: bool,
                  relocalised: bool) -> None:
        """A pose at time t; a new map starts a segment, a relocalised pose does not."""
        self.times.append(t)
        self.poses.append(T_w_c)
        if relocalised:
            self.relocalised.append(len(self.poses) - 1)
        self.segment.append(len(self.segment) and self.segment[-1]
                            + int(new_segment and not relocalised))


def camera_rate() -> Callable[[float], None]:
    """A function pace(t) that returns once as much wall time has passed since its first call
    as frame time t since the first frame's (at once when tracking is behind)."""
    first: list[tuple[float, float]] = []

    def pace(t: float) -> None:
        now = time.perf_counter()
        if not first:
            first.append((now, t))
        delay = (t - first[0][1]) - (now - first[0][0])
        if delay > 0:
            time.sleep(delay)

    return pace


def frame_row(result) -> dict:
    """The per-frame diagnostics of --frames-csv (without the error, known only at the end)."""
    return {"t": result.t, "quality": result.quality, "matches": result.n_matches,
            "attempts": result.n_attempts, "ransac_hypotheses": result.n_hypotheses,
            "inliers": result.n_inliers, "keyframe": int(result.keyframe),
            "new_segment": int(result.new_segment),
            "relocalized": int(getattr(result, "relocalized", False)),
            "merged": int(getattr(result, "merged", None) is not None),
            "held": int(getattr(result, "held", False)), "error_m": ""}


def write_frames_csv(path: Path, rows: list[dict], groundtruth: Trajectory | None,
                     estimate: Trajectory | None, align: str = "sim3") -> None:
    """Write the frame rows as CSV; error_m is the distance of each pose from the ground truth
    after the alignment (`align`) of the whole trajectory (as the ATE), empty without a pose
    or ground truth."""
    from sim.metrics import align_trajectories

    if groundtruth is not None and estimate is not None and len(estimate) >= 3:
        a = align_trajectories(groundtruth, estimate, align)
        errors = np.linalg.norm(a.groundtruth.positions - a.estimate.positions, axis=1)
        by_time = dict(zip(a.estimate.t.tolist(), errors.tolist(), strict=True))
        for row in rows:
            if row["t"] in by_time:
                row["error_m"] = f"{by_time[row['t']]:.6f}"
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(FRAME_COLUMNS))
        writer.writeheader()
        writer.writerows(rows)


def memory_sample(tracker, frame: int) -> dict:
    """Resident memory now (MB, Linux /proc) and the size of the tracker's map."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    m = tracker.map
    return {"frame": frame, "rss_mb": pages * resource.getpagesize() / 2**20,
            "keyframes": len(m.keyframes), "points": m.n_points(),
            "point_capacity": m.points.capacity, "observations": len(m.obs)}


def build_report(sequence, n_frames: int, estimate: Trajectory | None, segment: np.ndarray,
                 timings: list[dict[str, float]], qualities: list[str],
                 first_pose_s: float | None, align: str = "sim3") -> dict:
    """The numbers `sdvl track` prints, the ATE after the alignment `align`. Each map segment
    (a re-initialisation starts a new one) has its own scale and frame, so the ATE over
    several segments is only indicative; the longest segment's ATE is given too."""
    from sim.metrics import evaluate

    stats = stage_stats(timings)
    track = stats.get("track", {"median": None, "p95": None})
    report = {
        "sequence": sequence.name,
        "align": align,
        "frames": n_frames,
        "tracked": 0 if estimate is None else len(estimate),
        "ate_rmse_m": None,
        "rot_rmse_deg": None,
        "scale": None,
        "track_ms_median": track["median"],
        "track_ms_p95": track["p95"],
        "stages": {k: v["median"] for k, v in stats.items()},
        "stages_p95": {k: v["p95"] for k, v in stats.items()},
        "stages_mean": {k: v["mean"] for k, v in stats.items()},
        "qualities": {q: qualities.count(q) for q in sorted(set(qualities))},
        "first_pose_s": first_pose_s,
        "segments": int(segment.max()) + 1 if len(segment) else 0,
        "longest_segment_poses": 0,
        "longest_segment_ate_rmse_m": None,
        "longest_segment_rot_rmse_deg": None,
    }
    if sequence.groundtruth is not None and estimate is not None and len(estimate) >= 3:
        ev = evaluate(sequence.groundtruth, estimate, align)
        report.update(ate_rmse_m=ev.ate_rmse_m, rot_rmse_deg=ev.rot_rmse_deg, scale=ev.scale,
                      path_length_m=ev.path_length_m)
    if estimate is not None and len(segment):
        longest = np.bincount(segment).argmax()
        part = estimate.subset(segment == longest)
        report["longest_segment_poses"] = len(part)
        if sequence.groundtruth is not None and len(part) >= 3:
            ev = evaluate(sequence.groundtruth, part, align)
            report["longest_segment_ate_rmse_m"] = ev.ate_rmse_m
            report["longest_segment_rot_rmse_deg"] = ev.rot_rmse_deg
    return report


def late_note(late: int) -> str:
    """What `tracked` says of the poses given late (FrameResult.earlier)."""
    return (f", {late} of them late (the frames a new map's initialiser waited through, posed "
            "once the map existed; live: no pose)" if late else "")


def format_report(r: dict) -> str:
    """Human-readable lines of a report."""
    lines = [f"sequence   {r['sequence']}",
             f"frames     {r['frames']}",
             f"tracked    {r['tracked']} ({100.0 * r['tracked'] / max(r['frames'], 1):.1f}%)"
             + late_note(r.get("tracked_late", 0))]
    if r["ate_rmse_m"] is not None:
        label = {"sim3": "Sim3", "se3": "SE3"}.get(r["align"], r["align"])
        path = r.get("path_length_m")
        of_path = f", {100.0 * r['ate_rmse_m'] / path:.2f}% of the {path:.1f} m path" if path \
            else ""
        lines.append(f"ATE RMSE   {r['ate_rmse_m']:.4f} m ({label}{of_path}), rotation RMSE "
                     f"{r['rot_rmse_deg']:.2f} deg")
    else:
        lines.append("ATE RMSE   n/a (no ground truth)")
    if "first_depth_frame" in r:
        lines.append(f"first pose frame {r['first_pose_frame']} (first depth map: frame "
                     f"{r['first_depth_frame']})")
    if r["segments"] > 1:
        seg_ate = r["longest_segment_ate_rmse_m"]
        lines.append(f"segments   {r['segments']} (re-initialised); longest "
                     f"{r['longest_segment_poses']} poses"
                     + ("" if seg_ate is None else f", ATE RMSE {seg_ate:.4f} m, rotation "
                        f"RMSE {r['longest_segment_rot_rmse_deg']:.2f} deg"))
    if r.get("merges"):
        lines.append(f"merges     {r['merges']} (a map a re-initialisation replaced, joined "
                     "to the next one: one segment)")
    lines += format_relocalisations(r)
    lines.append("qualities  " + ", ".join(f"{k} {v}" for k, v in r["qualities"].items()))
    if "memory" in r:
        lines.append(f"peak RSS   {r['peak_rss_mb']:.0f} MB")
        lines.append("frame      RSS MB  keyframes  points  observations")
        lines += [f"{m['frame']:<9} {m['rss_mb']:7.0f} {m['keyframes']:10d} {m['points']:7d} "
                  f"{m['observations']:13d}" for m in r["memory"]]
    lines.append("stage          median ms    p95 ms")
    for name, med in r["stages"].items():
        lines.append(f"{name:<14} {med:9.2f} {r['stages_p95'][name]:9.2f}")
    if "profile" in r:
        from sim.track_profile import profile_lines

        lines += profile_lines(r["profile"])
    return "\n".join(lines)
