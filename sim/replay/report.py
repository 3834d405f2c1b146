"""Scores of a replay: what the autopilot received against the flown ground truth, the frame
accounting, message timing, latency and resources. `build_report` returns a flat JSON-ready dict
whose keys are stable (KEYS documents them)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sim.metrics import Aligned, align_trajectories, evaluate, interpolate
from sim.replay.autopilot_process import VisionMessage
from sim.replay.autopilot_scores import AUTOPILOT_KEYS, autopilot_scores
from sim.replay.fusion_scores import FUSION_KEYS, fusion_scores, velocity_at
from sim.replay.recording import stats_ms
from sim.replay.replay_run import ReplayRun
from sim.trajectory import Trajectory, write_tum
from vo.result import Quality

STAMP_TOLERANCE_S = 1e-4  # time_usec is t_capture in whole microseconds

KEYS = {
    "sequence": "sequence or preset name",
    "mode": "'realtime' (frames at their timestamps), 'fast' (as fast as tracking takes "
            "them) or 'lockstep' (fusion on a virtual clock; link timing keys are None)",
    "without": "sensors the autopilot did not stream",
    "estimator": "'fusion' (EKF) or 'pass-through'",
    "frames": "frames the camera source offered",
    "processed": "frames the tracker processed",
    "dropped": "frames offered but never processed (replaced by a newer one)",
    "drop_fraction": "dropped / frames",
    "tracked": "processed frames with a tracker pose",
    "tracked_fraction": "tracked / frames",
    "messages_received": "vision messages (ODOMETRY or VISION_POSITION_ESTIMATE) the "
                         "autopilot received",
    "skipped_stale": "estimates not sent because they were older than mavlink.max_latency_s",
    "scored": "received poses matched to ground truth",
    "align": "'sim3' (pass-through) or 'start' (fusion: translation to the first pose only)",
    "ate_rmse_m": "position error RMSE of the received poses after the alignment, metres",
    "ate_max_m": "largest position error, metres",
    "rot_rmse_deg": "attitude error RMSE after the alignment, degrees",
    "scale": "Sim(3) scale (1 for 'start')",
    "velocity_rmse_m_s": "velocity error RMSE of the received velocities, m/s",
    **FUSION_KEYS,
    "message_rate_hz": "received vision messages per second",
    "message_jitter_ms": "standard deviation of the intervals between arrivals, ms",
    "message_interval_ms_p99": "99th percentile of the intervals between arrivals, ms",
    "latency_ms_p50": "capture-to-send latency median, ms",
    "latency_ms_p95": "capture-to-send latency p95, ms",
    "latency_ms_p99": "capture-to-send latency p99, ms",
    "arrival_latency_ms_p99": "capture-to-arrival at the autopilot p99, ms",
    "tracking_ms_median": "tracker time per processed frame, median, ms",
    "tracking_ms_p95": "tracker time per processed frame, p95, ms",
    "cpu_ms_per_frame": "CPU time of the companion process per processed frame, ms",
    "peak_rss_mb": "peak resident memory of the companion process, MB",
    "resets": "changes of reset_counter in the received messages (discontinuities)",
    **AUTOPILOT_KEYS,
    "wall_s": "replay wall time (after warm-up), s",
    "warmup_s": "tracker warm-up before the replay started, s",
    "startup_s": "from the command to the first frame tracked, s (None in lockstep)",
    "received_file": "TUM file of the received poses (sequence time)",
    "groundtruth_file": "TUM file of the ground truth they are scored against",
}


@dataclass
class Received:
    """The received poses in sequence time, with what else each message carried."""

    trajectory: Trajectory
    velocity_local: np.ndarray  # (N, 3) in the message's local frame; NaN rows when absent
    position_cov: np.ndarray  # (N, 3, 3) local frame; NaN when absent
    velocity_cov: np.ndarray  # (N, 3, 3) local frame; NaN when absent
    t_capture: np.ndarray
    t_arrival: np.ndarray
    resets: int


def _pose_messages(received: list[VisionMessage]) -> list[VisionMessage]:
    odometry = [m for m in received if m.kind == "ODOMETRY"]
    return odometry or [m for m in received if m.kind == "VISION_POSITION_ESTIMATE"]


def _stamp(m: VisionMessage) -> float:
    """The capture time a vision message carries, seconds."""
    return (m.fields["time_usec"] if m.kind == "ODOMETRY" else m.fields["usec"]) / 1e6


def full_covariance(upper: list[float]) -> np.ndarray:
    """The 6x6 covariance of MAVLink's 21 row-major upper-triangle entries (NaN: unknown)."""
    C = np.full((6, 6), np.nan)
    if len(upper) == 21:
        C[np.triu_indices(6)] = upper
        C = np.where(np.isnan(C), C.T, C)
    return C


def _pose(m: VisionMessage, speeds: dict) -> tuple[np.ndarray, ...]:
    """position, quaternion xyzw, velocity, position and velocity covariances, all in the local
    frame (VISION_POSITION_ESTIMATE: velocity from the VISION_SPEED_ESTIMATE of the same frame,
    NaN without one)."""
    f = m.fields
    position = np.array([f["x"], f["y"], f["z"]])
    if m.kind == "ODOMETRY":
        w, x, y, z = f["q"]
        rot = Rotation.from_quat([x, y, z, w])
        R = rot.as_matrix()
        vel_cov = R @ full_covariance(f.get("velocity_covariance", []))[:3, :3] @ R.T
        return (position, rot.as_quat(), rot.apply([f["vx"], f["vy"], f["vz"]]),
                full_covariance(f.get("pose_covariance", []))[:3, :3], vel_cov)
    rot = Rotation.from_euler("ZYX", [f["yaw"], f["pitch"], f["roll"]])
    speed = speeds.get(f["usec"])
    velocity = np.full(3, np.nan) if speed is None else np.array([speed[k] for k in "xyz"])
    vel_cov = (np.reshape(speed["covariance"], (3, 3))
               if speed is not None and len(speed.get("covariance", [])) == 9
               else np.full((3, 3), np.nan))
    return (position, rot.as_quat(), velocity,
            full_covariance(f.get("covariance", []))[:3, :3], vel_cov)


def nearest(sorted_times: np.ndarray, times: np.ndarray, tolerance: float) -> np.ndarray:
    """Index of the nearest of `sorted_times` for each of `times`, -1 when none is within
    `tolerance`."""
    if len(sorted_times) == 0:
        return np.full(len(times), -1)
    k = np.clip(np.searchsorted(sorted_times, times), 1, max(len(sorted_times) - 1, 1))
    before = np.clip(k - 1, 0, len(sorted_times) - 1)
    k = np.where(np.abs(sorted_times[before] - times) <= np.abs(sorted_times[k] - times),
                 before, k) if len(sorted_times) > 1 else np.zeros(len(times), dtype=int)
    return np.where(np.abs(sorted_times[k] - times) <= tolerance, k, -1)


def received_poses(received: list[VisionMessage], rows: list[dict]) -> Received:
    """The pose messages in arrival order, each placed at its frame's sequence time (matched
    through the capture time it carries); messages that match no frame are left out."""
    speeds = {m.fields["usec"]: m.fields for m in received if m.kind == "VISION_SPEED_ESTIMATE"}
    rows = sorted(rows, key=lambda r: r["t_capture"])
    capture = np.array([r["t_capture"] for r in rows])
    messages = _pose_messages(received)
    index = nearest(capture, np.array([_stamp(m) for m in messages]), STAMP_TOLERANCE_S)
    matched = [(m, i) for m, i in zip(messages, index, strict=True) if i >= 0]
    poses = [_pose(m, speeds) for m, _ in matched]
    frames = [i for _, i in matched]
    counters = [m.fields["reset_counter"] for m, _ in matched]

    def column(k: int, shape: tuple[int, ...]) -> np.ndarray:
        return np.array([p[k] for p in poses], dtype=np.float64).reshape(-1, *shape)
    trajectory = Trajectory(np.array([rows[i]["t_source"] for i in frames]), column(0, (3,)),
                            column(1, (4,)))
    return Received(trajectory, column(2, (3,)), column(3, (3, 3)), column(4, (3, 3)),
                    capture[frames], np.array([m.t_arrival for m, _ in matched]),
                    int(np.count_nonzero(np.diff(counters))) if counters else 0)


def start_aligned(flight: Trajectory, estimate: Trajectory) -> Trajectory:
    """The flight translated so it passes through the first received position (the fusion's
    local NED frame has its origin where the vehicle was at its first tracked frame)."""
    at_start, _ = interpolate(flight, estimate.t[:1])
    shift = estimate.positions[0] - at_start.positions[0]
    return Trajectory(flight.t, flight.positions + shift, flight.quaternions)


def velocity_errors(aligned: Aligned, received: Received, groundtruth: Trajectory
                    ) -> np.ndarray:
    """Errors of the received velocities, rotated and scaled by the alignment (m/s), one row
    per aligned pose (NaN where the message had no velocity)."""
    index = np.searchsorted(received.trajectory.t, aligned.estimate.t)
    v = received.velocity_local[index]
    return aligned.scale * v @ aligned.R.T - velocity_at(groundtruth, aligned.estimate.t)


def rmse(errors: np.ndarray) -> float | None:
    """Root mean square of the finite error rows' norms."""
    ok = np.all(np.isfinite(errors), axis=1)
    return float(np.sqrt(np.mean(np.sum(errors[ok] ** 2, axis=1)))) if ok.any() else None


def _ms(value: float | None) -> float | None:
    return None if value is None else float(value)


def lockstep(run: ReplayRun) -> bool:
    """Whether the run was the fusion's lockstep replay (sim/replay/lockstep.py)."""
    return bool(run.stats.get("lockstep"))


def frame_counts(run: ReplayRun) -> dict:
    """Frame accounting."""
    processed = len(run.rows)
    tracked = sum(r["has_pose"] for r in run.rows)
    frames = run.offered
    return {"frames": frames, "processed": processed, "dropped": frames - processed,
            "drop_fraction": (frames - processed) / frames if frames else None,
            "tracked": tracked, "tracked_fraction": tracked / frames if frames else None}


def timing(run: ReplayRun, received: Received) -> dict:
    """Message rate and jitter, latencies, tracking time, CPU and memory (no link timing in
    lockstep: its arrival times are made up)."""
    linked = not lockstep(run)
    intervals = np.diff(received.t_arrival) * 1e3 if linked else np.zeros(0)
    span = received.t_arrival[-1] - received.t_arrival[0] if len(intervals) else 0.0
    send = stats_ms([r["send"] for r in run.rows if r["sent"]] if linked else [])
    arrival = stats_ms(list(received.t_arrival - received.t_capture) if linked else [])
    track = stats_ms([r["track"] for r in run.rows if r["quality"] != Quality.INITIALIZING])
    processed = len(run.rows)
    return {
        "message_rate_hz": len(intervals) / span if span > 0 else None,
        "message_jitter_ms": float(np.std(intervals)) if len(intervals) else None,
        "message_interval_ms_p99": (float(np.percentile(intervals, 99))
                                    if len(intervals) else None),
        "latency_ms_p50": _ms(send["median"]), "latency_ms_p95": _ms(send["p95"]),
        "latency_ms_p99": _ms(send["p99"]), "arrival_latency_ms_p99": _ms(arrival["p99"]),
        "tracking_ms_median": _ms(track["median"]), "tracking_ms_p95": _ms(track["p95"]),
        "cpu_ms_per_frame": 1e3 * run.cpu_s / processed if processed else None,
        "peak_rss_mb": run.peak_rss_mb,
    }


def accuracy(run: ReplayRun, received: Received,
             out_dir: Path | None) -> tuple[dict, Aligned | None, Trajectory | None]:
    """ATE, rotation and velocity errors, and the two TUM files `sdvl eval` agrees with."""
    align = "start" if run.fusion else "sim3"
    est = received.trajectory
    out = {"scored": 0, "align": align, "ate_rmse_m": None, "ate_max_m": None,
           "rot_rmse_deg": None, "scale": None, "velocity_rmse_m_s": None,
           "received_file": None, "groundtruth_file": None, **dict.fromkeys(FUSION_KEYS)}
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        out["received_file"] = str(out_dir / "received.txt")
        write_tum(est, out["received_file"])
    if run.flight is None or len(est) < 3:
        return out, None, None
    groundtruth = start_aligned(run.flight, est) if run.fusion else run.flight
    method = "none" if run.fusion else "sim3"
    if out_dir is not None:
        out["groundtruth_file"] = str(out_dir / "groundtruth.txt")
        write_tum(groundtruth, out["groundtruth_file"])
    ev = evaluate(groundtruth, est, method)
    aligned = align_trajectories(groundtruth, est, method)
    velocity_error = velocity_errors(aligned, received, groundtruth)
    out.update(scored=ev.matched, ate_rmse_m=ev.ate_rmse_m, ate_max_m=ev.ate_max_m,
               rot_rmse_deg=ev.rot_rmse_deg, scale=ev.scale,
               velocity_rmse_m_s=rmse(velocity_error))
    if run.fusion:
        index = np.searchsorted(est.t, aligned.estimate.t)
        tracked = [r["t_source"] for r in run.rows if r["has_pose"]]
        out.update(fusion_scores(aligned, groundtruth, velocity_error,
                                 received.position_cov[index], received.velocity_cov[index],
                                 min(tracked) if tracked else None, run.compass_bias_deg,
                                 run.stats.get("aligned_t")))
    return out, aligned, groundtruth


def build_report(run: ReplayRun, out_dir: Path | None
                 ) -> tuple[dict, Aligned | None, Trajectory | None]:
    """The report dictionary (keys: KEYS), the aligned trajectories and the whole ground truth
    they were scored against (in the received poses' frame for 'start'), for the plot."""
    received = received_poses(run.received, run.rows)
    scores, aligned, reference = accuracy(run, received, out_dir)
    mode = "realtime" if run.realtime else "lockstep" if lockstep(run) else "fast"
    report = {"sequence": run.name, "mode": mode, "without": list(run.without),
              "estimator": "fusion" if run.fusion else "pass-through",
              **frame_counts(run), "messages_received": len(received.t_arrival),
              "skipped_stale": run.stats.get("skipped_stale", 0),
              **scores, **timing(run, received), "resets": received.resets,
              **autopilot_scores(run.autopilot, run.flight_start, run.flight, run.received),
              "wall_s": run.wall_s, "warmup_s": run.warmup_s, "startup_s": run.startup_s}
    return {key: report[key] for key in KEYS}, aligned, reference


def _num(value: float | None, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}%"


def format_report(r: dict) -> str:
    """Human-readable lines of a report."""
    return "\n".join([
        f"replay     {r['sequence']} ({r['mode']}, {r['estimator']}), {r['wall_s']:.1f} s after "
        f"{r['warmup_s']:.1f} s tracker warm-up"
        + ("" if r["startup_s"] is None else
           f"; first frame tracked {r['startup_s']:.1f} s after the command"),
        f"frames     {r['frames']} offered, {r['processed']} processed, {r['dropped']} dropped "
        f"({_pct(r['drop_fraction'])})",
        f"tracked    {r['tracked']} ({_pct(r['tracked_fraction'])}), "
        f"resets {r['resets']}",
        f"received   {r['messages_received']} vision messages ({r['skipped_stale']} estimates "
        "too old to send), "
        f"{_num(r['message_rate_hz'], '.1f')} Hz, jitter {_num(r['message_jitter_ms'], '.1f')} ms"
        f" (interval p99 {_num(r['message_interval_ms_p99'], '.1f')} ms)",
        f"ATE RMSE   {_num(r['ate_rmse_m'], '.4f')} m ({r['align']} alignment, scale "
        f"{_num(r['scale'], '.4g')}, max {_num(r['ate_max_m'], '.4f')} m, {r['scored']} poses); "
        f"rotation {_num(r['rot_rmse_deg'], '.2f')} deg",
        f"velocity   RMSE {_num(r['velocity_rmse_m_s'], '.3f')} m/s",
        *_fusion_lines(r),
        *_autopilot_lines(r),
        f"latency    capture-to-send p50 {_num(r['latency_ms_p50'], '.1f')} / p95 "
        f"{_num(r['latency_ms_p95'], '.1f')} / p99 {_num(r['latency_ms_p99'], '.1f')} ms; "
        f"to arrival p99 {_num(r['arrival_latency_ms_p99'], '.1f')} ms",
        f"compute    tracking median {_num(r['tracking_ms_median'], '.1f')} ms (p95 "
        f"{_num(r['tracking_ms_p95'], '.1f')}), CPU {_num(r['cpu_ms_per_frame'], '.1f')} ms per "
        f"frame, peak RSS {r['peak_rss_mb']:.0f} MB",
        *_files_line(r),
    ])


def _fusion_lines(r: dict) -> list[str]:
    if r["estimator"] != "fusion" or r["distance_m"] is None:
        return []
    without = f" (without {', '.join(r['without'])})" if r["without"] else ""
    return [
        f"fusion     ATE {_num(r['ate_pct_distance'], '.2f')}% of {r['distance_m']:.1f} m flown"
        f"{without}; heading rms {_num(r['heading_rms_deg'], '.2f')} / max "
        f"{_num(r['heading_max_deg'], '.2f')} deg",
        f"           in the autopilot's heading frame (compass bias "
        f"{_num(r['compass_bias_deg'], '+.2f')} deg): heading rms "
        f"{_num(r['heading_frame_rms_deg'], '.2f')} / max {_num(r['heading_frame_max_deg'], '.2f')}"
        " deg,",
        f"           NEES per dof: position {_num(r['nees_position'], '.2f')}, velocity "
        f"{_num(r['nees_velocity'], '.2f')}",
        f"           tracking from {_num(r['tracking_start_s'], '.2f')} s, first published "
        f"{r['first_publish_s']:.2f} s; take-off {_num(r['takeoff_s'], '.2f')} s (climb "
        f"{r['climb_m']:.1f} m): published {_num(r['publish_after_takeoff_s'], '+.2f')} s, "
        f"aligned {_num(r['aligned_after_takeoff_s'], '+.2f')} s after it; errors beyond 3 "
        f"sigma {_pct(r['overconfident_fraction'])}"]


def _autopilot_lines(r: dict) -> list[str]:
    if r["first_reset_counter"] is None and r["arm_attempts"] is None:
        return []
    armed = ("never armed" if r["armed_s"] is None
             else f"armed at {r['armed_s']:+.1f} s")
    refusals = "; ".join(r["prearm_failures"] or []) or "none"
    extnav = ("never used our estimate" if r["extnav_s"] is None
              else f"EKF used our estimate from {r['extnav_s']:+.1f} s (height step "
                   f"{r['extnav_height_step_m']:.3f} m)")
    return [
        f"autopilot  {armed} ({r['arm_attempts']} attempts; refused: {refusals})",
        f"           {extnav}, largest height step {_num(r['max_height_step_m'], '.3f')} m; "
        f"first reset_counter {r['first_reset_counter']}, {r['position_resets']} position "
        f"resets, failsafes: {', '.join(r['failsafes'] or []) or 'none'}; its own error "
        f"{_num(r['autopilot_ate_m'], '.3f')} m (times from the flight's first frame)"]


def _files_line(r: dict) -> list[str]:
    if r["groundtruth_file"] is None:
        return [f"received   {r['received_file']}"] if r["received_file"] else []
    align = " --align none" if r["align"] == "start" else ""
    return [f"files      sdvl eval {r['groundtruth_file']} {r['received_file']}{align}"]
