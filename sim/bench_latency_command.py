"""`sdvl bench-latency`: how much the service adds to tracking between capture and the wire.

Runs the whole service (real tracker, capture thread, asyncio link) at the camera's rate against
the simulated autopilot over UDP loopback and prints, per stage, the median, p95 and p99 in
milliseconds: waiting for the tracker, tracking, capture-to-send and capture-to-arrival at the
autopilot. The target: capture-to-send p99 within 5 ms of the tracking p99 at 30 fps.

A sequence is played in real time like `sdvl replay --realtime` plays it (tracker warmed up first,
the autopilot flying the sequence's ground truth, the estimator `sdvl replay` picks: fusion for
synthetic flights, pass-through for hand-held datasets). The built-in test pattern uses the
pass-through (fusion needs autopilot sensors that move with the picture), tracker warmed up too.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time

from daemon.camera import TestPatternSource
from daemon.config import Config, load_config, replace
from daemon.run_command import camera_model, setup_logging, tracker_factory, warm_up
from daemon.service import Service, prefer_handoffs
from sim.autopilot import configured_options
from sim.replay.autopilot_process import AutopilotProcess, VisionMessage
from sim.replay.harness import choose_estimator, run_replay
from sim.replay.recording import Recorder, stats_ms
from vo.result import Quality

TARGET_MS = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl bench-latency`."""
    parser.add_argument("--sequence", default=None,
                        help="sequence folder, video, name in the shared data ($SDVL_DATA) or "
                             "synthetic preset, played in real time (default: the built-in "
                             "test pattern)")
    parser.add_argument("--fps", type=float, default=30.0,
                        help="test-pattern frame rate (default 30)")
    parser.add_argument("--frames", type=int, default=600,
                        help="frames to measure after the warm-up (default 600; a sequence "
                             "offers at most this many plus the warm-up)")
    parser.add_argument("--warmup", type=int, default=30,
                        help="frames left out after the first one sent from a tracked map "
                             "(default 30); frames before it are never measured")
    parser.add_argument("--config", default=None, help="service config (tracker, mounting)")
    parser.add_argument("--inline-mapping", action="store_true",
                        help="map in the tracking thread instead of a mapping thread")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


# processed frames the test pattern may take to send (~35 on a quiet machine; more on a cold cache)
START_LIMIT = 900


def first_sent(rows: list[dict]) -> int:
    """Index of the first row whose estimate was sent at quality good (a map tracked: the poses
    at rest sent before a map, quality insufficient, end when the camera moves, and the map
    can start tens of frames later), len(rows) if none."""
    return next((i for i, r in enumerate(rows) if r["sent"] and r["quality"] == Quality.GOOD),
                len(rows))


async def measure(service: Service, recorder: Recorder, frames: int) -> None:
    """Run the service until `frames` frames were processed after the first one sent, or the
    source ended, or START_LIMIT frames passed without one."""
    task = asyncio.create_task(service.run())
    while not task.done():
        rows = recorder.rows
        start = first_sent(rows)
        if len(rows) - start >= frames or (start == len(rows) and start >= START_LIMIT):
            break
        await asyncio.sleep(0.1)
    service.stop()
    await task


def report(rows: list[dict], received: list[VisionMessage], warmup: int, dropped: int,
           estimator: str) -> dict:
    """The numbers from the Recorder rows of the processed frames and what the autopilot
    received, frames from the first one sent from a tracked map and the warm-up after it (the
    frames before would measure how long the map takes to start, not the service)."""
    rows = rows[first_sent(rows) + warmup:]
    first = rows[0]["t_capture"] if rows else float("inf")
    stamps = [(m.fields["time_usec"] / 1e6, m.t_arrival) for m in received
              if m.kind in ("ODOMETRY", "VISION_POSITION_ESTIMATE")]
    arrivals = [arrival - stamp for stamp, arrival in stamps if stamp >= first]
    sent = [r for r in rows if r["sent"]]
    out = {
        "estimator": estimator, "frames": len(rows), "sent": len(sent),
        "dropped_by_capture": dropped,
        "wait_for_tracker_ms": stats_ms([r["wait"] for r in rows]),
        "tracking_ms": stats_ms([r["track"] for r in rows]),
        "tracking_of_sent_ms": stats_ms([r["track"] for r in sent]),
        "capture_to_send_ms": stats_ms([r["send"] for r in sent]),
        "service_overhead_ms": stats_ms([r["send"] - r["wait"] - r["track"] for r in sent]),
        "estimator_ms": stats_ms([r["estimate"] for r in sent]),
        "handoff_and_send_ms": stats_ms([r["handoff"] for r in sent]),
        "capture_to_arrival_ms": stats_ms(arrivals),
    }
    if sent:
        out["p99_difference_ms"] = (out["capture_to_send_ms"]["p99"]
                                    - out["tracking_of_sent_ms"]["p99"])
        out["within_target"] = out["p99_difference_ms"] <= TARGET_MS
    return out


def print_report(r: dict) -> None:
    print(f"estimator {r['estimator']}: frames measured {r['frames']}, vision messages sent "
          f"{r['sent']}, dropped by capture {r['dropped_by_capture']} (whole run, warm-up "
          "included)")
    print(f"{'stage':28} {'median':>8} {'p95':>8} {'p99':>8}   ms")
    for key in ("wait_for_tracker_ms", "tracking_ms", "tracking_of_sent_ms",
                "capture_to_send_ms", "service_overhead_ms", "estimator_ms",
                "handoff_and_send_ms", "capture_to_arrival_ms"):
        s = r[key]
        if s["n"]:
            print(f"{key[:-3]:28} {s['median']:8.2f} {s['p95']:8.2f} {s['p99']:8.2f}")
    if "p99_difference_ms" in r:
        verdict = "within" if r["within_target"] else "OVER"
        print(f"capture-to-send p99 - tracking p99 = {r['p99_difference_ms']:.2f} ms "
              f"({verdict} the {TARGET_MS:g} ms target)")


def run(args: argparse.Namespace) -> int:
    """Entry point of `sdvl bench-latency`."""
    from sim.track_command import resolve_sequence

    config = load_config(args.config) if args.config else Config()
    setup_logging("warning")
    if args.inline_mapping:
        config = replace(config, service={"mapping_thread": False})
    if args.sequence:
        sequence = resolve_sequence(args.sequence)
        config = choose_estimator(config, sequence, "auto")
        replay = run_replay(sequence, config, True, args.frames + args.warmup, progress=False)
        result = report(replay.rows, replay.received, args.warmup,
                        replay.offered - len(replay.rows), _estimator(config))
    else:
        result = bench_test_pattern(replace(config, fusion={"enabled": False}), args)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_report(result)
    return 0


def _estimator(config: Config) -> str:
    return "fusion" if config.fusion.enabled else "pass-through"


def bench_test_pattern(config: Config, args: argparse.Namespace) -> dict:
    """The service on the built-in test pattern at args.fps until args.frames + args.warmup
    frames were processed, the tracker warmed up first as `sdvl replay` does (a cold kernel
    cache compiled for seconds in the middle of tracking, and the moving pattern was lost)."""
    width, height = 320, 240
    source = TestPatternSource(width, height, args.fps)
    autopilot = AutopilotProcess(configured_options())
    try:
        config = replace(config, mavlink={"link": autopilot.url, "output": "odometry"},
                         camera={"source": "testpattern", "calibration": ""})
        make_tracker = tracker_factory(config, camera_model(config.camera, source))
        warm_up(make_tracker, width, height)
        recorder = Recorder()
        service = Service(config, source, make_tracker, on_tracked=recorder)
        prefer_handoffs()
        asyncio.run(measure(service, recorder, args.frames + args.warmup))
        time.sleep(0.2)
    finally:
        received = autopilot.finish().vision
    return report(recorder.rows, received, args.warmup, service.capture.slot.dropped,
                  _estimator(config))
