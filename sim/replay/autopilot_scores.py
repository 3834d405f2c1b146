"""What the simulated autopilot made of a replay (its record, sim/autopilot/records.py): whether
the pilot could arm it and why not, when its EKF started using our estimate, how its height
stepped then and at every reset, which reset_counter it heard first, failsafes, and how far its
own estimate was from the truth. Times are seconds from the flight's first frame (negative:
during the pre-flight on the ground)."""

from __future__ import annotations

import numpy as np

from sim.autopilot.records import EventKind
from sim.replay.autopilot_process import AutopilotOutcome, VisionMessage
from sim.trajectory import Trajectory

AUTOPILOT_KEYS = {
    "armed_s": "when the pilot could arm (None: never), s from the flight's first frame",
    "arm_attempts": "arming attempts the pilot made (one a second on the ground)",
    "prearm_failures": "the distinct 'PreArm: ...' texts the autopilot answered with",
    "extnav_s": "when the autopilot's EKF started using our estimate (None: never), s",
    "extnav_height_step_m": "its height step when it started using our estimate, m",
    "max_height_step_m": "largest height step of any of its height resets, m",
    "first_reset_counter": "reset_counter of the first vision message it received",
    "position_resets": "position resets our reset_counter changes caused",
    "failsafes": "failsafes it declared",
    "autopilot_ate_m": "RMSE of its own position estimate while using ours, against the "
                       "truth (translation-aligned where it started using ours), m",
}


def autopilot_scores(outcome: AutopilotOutcome | None, start: tuple[float, float] | None,
                     flight: Trajectory | None, received: list[VisionMessage]) -> dict:
    """AUTOPILOT_KEYS for a replay with the autopilot in the loop (all None without one);
    `start` = (sequence time, capture time) of the flight's first frame."""
    out = dict.fromkeys(AUTOPILOT_KEYS)
    if outcome is None or start is None:
        return out
    record = outcome.record
    start_t, start_capture = start

    def since(event: object) -> float | None:
        return None if event is None else float(event.t - start_capture)

    extnav = record.first(EventKind.EXTNAV_STARTED)
    steps = record.of(EventKind.HEIGHT_RESET)
    at_start = [e for e in steps if extnav is not None and abs(e.t - extnav.t) < 1e-6]
    pose = [m for m in received if m.kind in ("ODOMETRY", "VISION_POSITION_ESTIMATE")]
    out.update(
        armed_s=since(record.first(EventKind.ARMED)),
        arm_attempts=len(outcome.arm_attempts),
        prearm_failures=sorted({s.text for s in record.statustexts
                                if s.text.startswith("PreArm")}),
        extnav_s=since(extnav),
        extnav_height_step_m=abs(at_start[0].value) if at_start else (0.0 if extnav else None),
        max_height_step_m=max((abs(e.value) for e in steps), default=0.0),
        first_reset_counter=pose[0].fields.get("reset_counter") if pose else None,
        position_resets=len(record.of(EventKind.POSITION_RESET)),
        failsafes=[e.detail for e in record.of(EventKind.FAILSAFE)],
        autopilot_ate_m=_estimate_error(record.estimates, start_t - start_capture, flight))
    return out


def _estimate_error(estimates: list, to_sequence: float,
                    flight: Trajectory | None) -> float | None:
    """RMSE of the autopilot's estimate while using vision against the flight, both moved to
    agree where it started using vision (its origin is not the flight's); `to_sequence` maps
    its clock to sequence time."""
    using = [s for s in estimates if s.using_vision]
    if flight is None or len(using) < 2:
        return None
    t = np.array([s.t for s in using]) + to_sequence
    inside = (t >= flight.t[0]) & (t <= flight.t[-1])
    if inside.sum() < 2:
        return None
    truth = np.stack([np.interp(t[inside], flight.t, flight.positions[:, i]) for i in range(3)],
                     axis=1)
    estimate = np.array([s.position for s in using])[inside]
    error = (estimate - estimate[0]) - (truth - truth[0])
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
