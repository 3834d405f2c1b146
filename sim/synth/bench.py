"""Rendering speed: `python -m sim.synth.bench [--presets ...] [--frames N] [--size WxH]`
prints per-frame median and p95 milliseconds of ray casting and of the imaging effects (no
motion blur), one core: wall-clock time and this thread's CPU time (what a shared, loaded
machine does not inflate)."""

from __future__ import annotations

import argparse
import time

import numpy as np

from sim.render_command import parse_size
from sim.synth.effects import exposure_gain, finish
from sim.synth.flight import synthetic_sequence


def bench_preset(preset: str, frames: int, size: tuple[int, int]) -> dict[str, np.ndarray]:
    """Milliseconds per stage for `frames` frames spread over the preset."""
    seq = synthetic_sequence(preset, size=size)
    renderer = seq.image_loader
    renderer.ideal(0.0)  # compile / load the kernels outside the timing
    times = {"render": [], "effects": [], "render cpu": [], "effects cpu": []}
    rng = np.random.default_rng(0)
    for t in np.linspace(0.0, float(seq.timestamps[-1]), frames):
        start, cpu0 = time.perf_counter(), time.thread_time()
        image, _ = renderer.ideal(float(t))
        mid, cpu1 = time.perf_counter(), time.thread_time()
        gain = exposure_gain(renderer.spec.effects, float(t), 0.0)
        finish(image, seq.camera, renderer.spec.effects, gain, rng)
        end, cpu2 = time.perf_counter(), time.thread_time()
        times["render"].append((mid - start) * 1e3)
        times["effects"].append((end - mid) * 1e3)
        times["render cpu"].append((cpu1 - cpu0) * 1e3)
        times["effects cpu"].append((cpu2 - cpu1) * 1e3)
    return {k: np.array(v) for k, v in times.items()}


def main(argv: list[str] | None = None) -> int:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presets", nargs="+",
                        default=["hover-down", "survey-down", "room-handheld", "walkers"])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--size", default="640x480")
    args = parser.parse_args(argv)
    size = parse_size(args.size)
    print(f"{'preset':16s} {'stage':12s} {'median ms':>10s} {'p95 ms':>8s} {'fps':>8s}")
    for preset in args.presets:
        ms = bench_preset(preset, args.frames, size)
        ms["total"] = ms["render"] + ms["effects"]
        ms["total cpu"] = ms["render cpu"] + ms["effects cpu"]
        for stage, values in ms.items():
            fps = f"{1e3 / np.median(values):8.1f}" if stage.startswith("total") else ""
            print(f"{preset:16s} {stage:12s} {np.median(values):10.1f} "
                  f"{np.percentile(values, 95):8.1f} {fps}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
