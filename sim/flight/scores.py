"""What a closed-loop flight did, in the figures a user acts on: each step's outcome, when the
autopilot started using our estimate, the hold drift and the square's corner errors in truth,
the autopilot's height steps, failsafes, the latency its VISO_DELAY_MS must hold; and the
expert figures of `sdvl replay` (ATE, NEES, heading frames) of the messages it received.

Truth targets: a goto's target is in the autopilot's local frame; the truth it is scored against
is the vehicle's true position when it armed plus the target's offset from the autopilot's own
position then (what a pilot means by "2 m north of where it took off").
"""

from __future__ import annotations

import resource
from dataclasses import dataclass

import numpy as np

from daemon.latency import ardupilot_delay_ms
from sim.autopilot.records import EventKind
from sim.flight.flight_run import FlightRun
from sim.flight.mission import Action
from sim.flight.runner import Outcome, StepResult
from sim.replay.fusion_scores import takeoff_time
from sim.replay.harness import ReplayRun
from sim.replay.report import build_report

FAILSAFE_WORDS = ("failsafe", "EKF variance")


@dataclass(frozen=True)
class HoldScore:
    """A hold step in truth: the largest horizontal and vertical distance from where it
    started, metres."""

    mode: str
    seconds: float
    drift_xy_m: float
    drift_z_m: float


@dataclass(frozen=True)
class CornerScore:
    """A goto in truth: its target (north, east, up from home) and the horizontal and vertical
    distance from it after the settle time (None: never arrived by the autopilot's estimate),
    metres."""

    target: tuple[float, float, float]
    error_xy_m: float | None
    error_z_m: float | None


@dataclass(frozen=True)
class HeightErrors:
    """While airborne (take-off to landing), the largest error in truth of the height the
    autopilot estimated itself and of ours, both from the arming point, metres."""

    autopilot_m: float | None
    ours_m: float | None


@dataclass(frozen=True)
class HeightStep:
    """A jump of the autopilot's height estimate (an EKF reset)."""

    t: float
    step_m: float
    why: str


@dataclass
class FlightScores:
    """The scored flight (see the module doc); `expert` is `sdvl replay`'s report dict."""

    steps_done: int
    failed: StepResult | None
    armed: bool
    takeoff_s: float | None
    extnav_s: float | None
    holds: list[HoldScore]
    corners: list[CornerScore]
    heights: HeightErrors
    height_steps: list[HeightStep]
    failsafes: list[str]
    latency_ms: list[float]
    suggested_delay_ms: float | None
    viso_delay_ms: float | None
    expert: dict

    @property
    def extnav_after_takeoff_s(self) -> float | None:
        """Seconds from lift-off until the autopilot used our estimate (negative: before)."""
        if self.extnav_s is None or self.takeoff_s is None:
            return None
        return self.extnav_s - self.takeoff_s


def truth_at(run: FlightRun, t: float | np.ndarray) -> np.ndarray:
    """The vehicle's true position (NED) at time t (or times t: one row each), linear between
    truth samples and held beyond them."""
    truth = run.truth
    return np.stack([np.interp(t, truth.t, truth.positions[:, k]) for k in range(3)], axis=-1)


def hold_scores(run: FlightRun) -> list[HoldScore]:
    """Each finished hold step in truth, with the mode set before it."""
    out, mode = [], "?"
    for r in run.steps:
        if r.step.action is Action.MODE:
            mode = r.step.value
        if r.step.action is not Action.HOLD or r.ended is None:
            continue
        inside = (run.truth.t >= r.started) & (run.truth.t <= r.ended)
        p = run.truth.positions[inside]
        if len(p) < 2:
            continue
        d = p - p[0]
        out.append(HoldScore(mode, r.ended - r.started,
                             float(np.max(np.linalg.norm(d[:, :2], axis=1))),
                             float(np.max(np.abs(d[:, 2])))))
    return out


def _arming(run: FlightRun) -> StepResult | None:
    return next((r for r in run.steps if r.step.action is Action.ARM and r.home is not None),
                None)


def frame_offset(run: FlightRun) -> np.ndarray | None:
    """Truth minus the autopilot's local frame: where the vehicle truly was when it armed less
    where the autopilot thought it was (before any arming: at its first estimate)."""
    arm = _arming(run)
    if arm is not None:
        return truth_at(run, arm.ended) - arm.home
    if run.record.estimates and len(run.truth):
        first = run.record.estimates[0]
        return truth_at(run, first.t) - first.position
    return None


def corner_scores(run: FlightRun) -> list[CornerScore]:
    """Each goto step's truth error (see the module doc)."""
    arm, offset = _arming(run), frame_offset(run)
    out = []
    for r in run.steps:
        if r.step.action is not Action.GOTO or r.target is None or arm is None:
            continue
        north, east, down = r.target - arm.home
        target = (float(north), float(east), float(-down))
        if r.outcome is not Outcome.DONE:
            out.append(CornerScore(target, None, None))
            continue
        error = truth_at(run, r.ended) - (r.target + offset)
        out.append(CornerScore(target, float(np.linalg.norm(error[:2])), float(abs(error[2]))))
    return out


def _airborne(run: FlightRun) -> tuple[float, float] | None:
    """From the take-off command to the landing command (or the end)."""
    start = next((r.started for r in run.steps if r.step.action is Action.TAKEOFF), None)
    end = next((r.started for r in run.steps if r.step.action is Action.LAND),
               float(run.truth.t[-1]) if len(run.truth) else None)
    return None if start is None or end is None or end <= start else (start, end)


def _height_error(run: FlightRun, t: np.ndarray, down: np.ndarray, t_arm: float) -> float | None:
    """Largest |estimated - true| height from the arming point over the samples (t, NED z)."""
    window = _airborne(run)
    if window is None or len(t) < 2:
        return None
    inside = (t >= window[0]) & (t <= window[1])
    if not inside.any():
        return None
    at_arm = float(np.interp(t_arm, t, down))
    truth_arm = truth_at(run, t_arm)[2]
    true_down = truth_at(run, t[inside])[:, 2]
    return float(np.max(np.abs((down[inside] - at_arm) - (true_down - truth_arm))))


def height_errors(run: FlightRun) -> HeightErrors:
    """The autopilot's own height and ours against the truth while airborne."""
    arm = _arming(run)
    if arm is None:
        return HeightErrors(None, None)
    ap = run.record.estimates
    ours_t = np.array([m.fields["time_usec"] / 1e6 for m in run.sent]) - run.timing.our_clock_s
    return HeightErrors(
        _height_error(run, np.array([e.t for e in ap]),
                      np.array([e.position[2] for e in ap]), arm.ended),
        _height_error(run, ours_t, np.array([m.fields["z"] for m in run.sent]), arm.ended))


def height_steps(run: FlightRun) -> list[HeightStep]:
    """The autopilot's height resets with their size."""
    return [HeightStep(e.t, abs(e.value), e.detail)
            for e in run.record.of(EventKind.HEIGHT_RESET)]


def failsafes(run: FlightRun) -> list[str]:
    """The autopilot's failsafe texts, with their times."""
    return [f"{s.t:.1f} s {s.text}" for s in run.record.statustexts
            if any(w.lower() in s.text.lower() for w in FAILSAFE_WORDS)]


def latencies_ms(run: FlightRun) -> list[float]:
    """Capture to arrival at the autopilot of each vision message, ms."""
    return [1e3 * (m.t_arrival - m.fields["time_usec"] / 1e6) for m in run.sent]


def replay_run(run: FlightRun) -> ReplayRun:
    """The flight as `sdvl replay`'s report reads a run."""
    bias = (float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(run.compass_errors_deg))))))
            if run.compass_errors_deg else None)
    return ReplayRun(
        name=f"{run.mission.name} ({run.mission.world} world)", realtime=run.realtime,
        fusion=True, offered=len(run.rows) if run.offered is None else run.offered,
        rows=run.rows, received=run.sent, flight=run.truth,
        wall_s=run.wall_s, cpu_s=run.cpu_s, warmup_s=0.0, peak_rss_mb=_peak_rss_mb(),
        exit_code=0, stats={"sent": len(run.sent), "lockstep": not run.realtime},
        without=run.without, compass_bias_deg=bias)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def score(run: FlightRun) -> FlightScores:
    """Everything the report says about one flight."""
    expert, _, _ = build_report(replay_run(run), None)
    latency = latencies_ms(run)
    suggested = (ardupilot_delay_ms([v / 1e3 for v in latency], [], "closed loop")[0]
                 if latency else None)
    takeoff, _ = takeoff_time(run.truth, float(run.truth.t[0])) if len(run.truth) else (None, 0)
    extnav = run.record.first(EventKind.EXTNAV_STARTED)
    failed = next((r for r in run.steps if r.outcome in (Outcome.FAILED, Outcome.TIMEOUT)),
                  None)
    return FlightScores(
        steps_done=sum(r.outcome is Outcome.DONE for r in run.steps), failed=failed,
        armed=any(r.step.action is Action.ARM and r.outcome is Outcome.DONE
                  for r in run.steps),
        takeoff_s=takeoff, extnav_s=None if extnav is None else extnav.t,
        holds=hold_scores(run), corners=corner_scores(run), heights=height_errors(run),
        height_steps=height_steps(run),
        failsafes=failsafes(run), latency_ms=latency, suggested_delay_ms=suggested,
        viso_delay_ms=run.viso_delay_ms, expert=expert)
