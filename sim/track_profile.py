"""`sdvl track --profile N`: where a frame's time goes, function by function.

The tracker's calls (tracking, and mapping when it runs in the same thread, the default) run
under cProfile; image loading and the report do not. A numba kernel's time counts as its
Python caller's own time (cProfile does not see into compiled code), so a stage's function with
a large own time is either Python work or the kernels it calls. Per frame: own time, time
including callees, and Python calls; the total Python calls per frame is the overhead the
issue's "fewer Python calls per frame" counts. The slowest frames follow, each with its state
and stages: where the p95 comes from.
"""

from __future__ import annotations

import cProfile
import pstats
from collections.abc import Callable
from pathlib import Path

from vo.result import Quality

SLOWEST = 5  # frames listed by --profile


class FrameProfiler:
    """Profiles the calls made through `wrap`; `rows` summarises them per frame."""

    def __init__(self):
        self.profile = cProfile.Profile()
        self.frames = 0
        # index, quality and stages of each frame timed as the report's stages are
        self.per_frame: list[tuple[int, str, dict[str, float]]] = []

    def wrap(self, offer: Callable) -> Callable:
        """`offer` (image, t) -> result, profiled."""
        def profiled(image, t):
            self.frames += 1
            self.profile.enable()
            try:
                result = offer(image, t)
            finally:
                self.profile.disable()
            if result is not None and result.quality != Quality.INITIALIZING:
                self.per_frame.append((self.frames - 1, str(result.quality), result.timings))
            return result
        return profiled

    def rows(self, top: int) -> dict:
        """The `top` functions by own time: ms per frame own and cumulative, calls per frame;
        and the Python calls per frame over all functions."""
        stats = pstats.Stats(self.profile).stats
        n = max(self.frames, 1)
        ranked = sorted(stats.items(), key=lambda kv: kv[1][2], reverse=True)[:top]
        functions = [{"function": _name(where), "own_ms": own * 1e3 / n,
                      "cum_ms": cum * 1e3 / n, "calls": calls / n}
                     for where, (_, calls, own, cum, _) in ranked]
        slowest = sorted(self.per_frame, key=lambda f: -f[2]["track"])[:SLOWEST]
        return {"frames": self.frames, "calls_per_frame": sum(v[1] for v in stats.values()) / n,
                "functions": functions,
                "slowest": [{"frame": i, "quality": q, "stages": dict(st)}
                            for i, q, st in slowest]}


def _name(where: tuple[str, int, str]) -> str:
    """module/file:line function, the file relative to the project or the library."""
    file, line, name = where
    if file == "~":  # a built-in
        return name
    parts = Path(file).parts
    for anchor in ("site-packages", "vo", "sim", "daemon", "calib", "sdvl"):
        if anchor in parts:
            i = len(parts) - 1 - parts[::-1].index(anchor)
            parts = parts[i + (anchor == "site-packages"):]
            break
    return f"{'/'.join(parts)}:{line} {name}"


def profile_lines(profile: dict) -> list[str]:
    """The profile as report lines."""
    lines = [f"profile    {profile['calls_per_frame']:.0f} Python calls per frame over "
             f"{profile['frames']} frames; by own time:",
             "  own ms/frame  cum ms/frame  calls/frame  function"]
    lines += [f"  {f['own_ms']:12.3f}  {f['cum_ms']:12.3f}  {f['calls']:11.1f}  {f['function']}"
              for f in profile["functions"]]
    lines.append("slowest frames (ms, under the profiler):")
    lines += [f"  frame {f['frame']:<6} {f['quality']:<13} " + ", ".join(
        f"{k} {v:.2f}" for k, v in sorted(f["stages"].items(), key=lambda kv: -kv[1]))
        for f in profile["slowest"]]
    return lines
