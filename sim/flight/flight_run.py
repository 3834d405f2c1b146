"""What a closed-loop flight leaves for its report: the timing it ran with and the record of
everything that happened (FlightRun), the same for the virtual-clock and the real-time loop."""

from __future__ import annotations

from dataclasses import dataclass, field

from sim.autopilot.records import AutopilotRecord
from sim.flight.mission import Mission
from sim.flight.runner import StepResult
from sim.replay.autopilot_process import VisionMessage
from sim.trajectory import Trajectory


@dataclass(frozen=True)
class Timing:
    """The loop's clock and latencies, seconds (the real-time loop measures its own)."""

    fps: float = 30.0
    capture_to_send_s: float = 0.035  # autopilot-interface.md (e) 7: 31-38 ms measured
    link_s: float = 0.003  # an ODOMETRY frame (257 bytes) at 921600 baud
    gcs_link_s: float = 0.02  # a telemetry radio, one way
    step_s: float = 0.0025  # ArduCopter's 400 Hz main loop
    our_clock_s: float = 5000.0  # our monotonic clock when the autopilot boots
    drop_share: float = 0.0  # frames the service drops in runs, a busy machine's (frame_drops.py)


@dataclass
class FlightRun:
    """Everything the report scores, times in seconds since the autopilot booted (our clock is
    that plus `timing.our_clock_s`)."""

    mission: Mission
    seed: int
    without: tuple[str, ...]
    timing: Timing
    truth: Trajectory  # body FRD in NED, the world's frame
    steps: list[StepResult]
    sent: list[VisionMessage]  # t_arrival: when it reached the autopilot (our clock)
    rows: list[dict]  # one per tracked frame, as the replay's recorder
    record: AutopilotRecord
    viso_delay_ms: float | None
    compass_errors_deg: list[float] = field(default_factory=list)
    realtime: bool = False
    wall_s: float = 0.0
    cpu_s: float = 0.0
    load: int = 0  # busy processes beside a real-time flight
    offered: int | None = None  # frames the camera gave (None: every frame was tracked)
