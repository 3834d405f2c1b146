"""What a replay hands between its parts: the frames it plays (FirstFrames) and everything
its report scores (ReplayRun), for the real-time harness and the lockstep loop alike."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

from sim.replay.autopilot_process import AutopilotOutcome, VisionMessage
from sim.trajectory import Trajectory


@dataclass
class FirstFrames:
    """A sequence cut to its first `limit` frames (None: all), for SequenceSource."""

    sequence: object
    limit: int | None

    @property
    def name(self) -> str:
        return self.sequence.name

    @property
    def camera(self) -> object:
        return self.sequence.camera

    def __len__(self) -> int:
        n = len(self.sequence)
        return n if self.limit is None else min(n, self.limit)

    def frames(self):
        """(t, image) of the first frames."""
        return self.sequence.frames(self.limit)

    @property
    def has_depth(self) -> bool:
        return getattr(self.sequence, "has_depth", False)

    def depth(self, index: int) -> object:
        """Frame `index`'s depth map (sim.sequence.Sequence.depth)."""
        return self.sequence.depth(index)


@dataclass
class ReplayRun:
    """Everything the report scores."""

    name: str
    realtime: bool
    fusion: bool
    offered: int
    rows: list[dict]  # Recorder rows, one per processed frame
    received: list[VisionMessage]
    flight: Trajectory | None  # vehicle ground truth (body FRD in NED)
    wall_s: float
    cpu_s: float
    warmup_s: float
    peak_rss_mb: float
    exit_code: int
    stats: dict = field(default_factory=dict)
    without: tuple[str, ...] = ()  # sensors the autopilot did not stream
    compass_bias_deg: float | None = None  # of the simulated autopilot's attitude
    autopilot: AutopilotOutcome | None = None  # its record (not in lockstep)
    flight_start: tuple[float, float] | None = None  # (t_source, t_capture): its first frame
    startup_s: float | None = None  # from the process's start to its first frame tracked


def since_process_start(t_monotonic: float) -> float | None:
    """Seconds from this process's start (Linux /proc: its start in clock ticks after boot) to
    the time.monotonic() time `t_monotonic`; None where /proc does not tell."""
    try:
        with open("/proc/self/stat") as f:
            started = int(f.read().rsplit(")", 1)[1].split()[19]) / os.sysconf("SC_CLK_TCK")
        with open("/proc/uptime") as f:
            age = float(f.read().split()[0]) - started
    except (OSError, ValueError, IndexError):
        return None
    return t_monotonic - (time.monotonic() - age)


def aligned_time(estimator: object, rows: list[dict]) -> float | None:
    """Sequence time of the frame at which the fusion's map first aligned (None: never, or no
    fusion)."""
    capture = getattr(estimator, "first_aligned_s", None)
    return next((r["t_source"] for r in rows if r["t_capture"] == capture), None)
