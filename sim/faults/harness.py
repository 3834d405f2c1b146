"""Faults on the autopilot link, played in lockstep through the service's receiving side and the
fusion filter, and scored against the truth.

A simulated flight (sim/fusion_sim.py: the autopilot's messages and the tracker's results from
the same truth) becomes a stream of MAVLink packets with valid CRCs, which a scenario
(scenarios.py) changes. Each packet is decoded by the service's own codec, judged by its
autopilot watch (one bound autopilot, its boot clock: autopilot_watch.py) and what passes goes
to a FusionEstimator, on a virtual clock, with the tracker's frames in between. What the
service would publish is scored: crashes, estimates with NaN or infinity, stale or repeated
stamps, positions whose error is beyond 3 standard deviations on any axis of the covariance
sent with them, resets, and how long after the fault it is publishing good poses again.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from daemon.autopilot_watch import AutopilotWatch
from daemon.config import MountingConfig
from daemon.fusion.estimator import FusionEstimator
from daemon.mavlink_codec import MavlinkCodec
from daemon.service import not_finite
from sim import fusion_sim
from sim.replay.fusion_scores import turned_about_down

HEARTBEAT_TIMEOUT_S = 3.0
RECOVERED_FOR_S = 1.0  # recovered: published this long without a gap ...
MAX_GAP_S = 0.2  # ... longer than this (PX4 stops fusing after 200 ms) ...
RECOVERED_SHARE = 0.9  # ... with at least this share of positions within 3 sigma
SIGMAS = 3.0


@dataclass(frozen=True)
class Packet:
    """Bytes arriving from the link at `arrival` (our clock, seconds)."""

    arrival: float
    data: bytes


@dataclass
class Stream:
    """What one scenario feeds the service: packets and tracker frames in arrival order."""

    flight: fusion_sim.Flight
    packets: list[Packet]
    fault: tuple[float, float]  # flight time the fault starts and ends
    injected: int  # packets the fault changed or added (or garbage bytes sent, in packets)


@dataclass
class Outcome:
    """Everything a run produced: per frame (t_capture, estimate or None), the errors raised
    inside the receiving side or the filter, and the watch's counters."""

    estimates: list[tuple[float, object]]
    errors: Counter
    ignored: dict
    reboots: int = 0  # reboots the autopilot watch recognised


@dataclass
class FaultScore:
    """One scenario's score (positions scored in the autopilot's heading frame, from the first
    published position, as sim/fusion_sim.py scores the filter)."""

    scenario: str
    injected: int
    crashes: int
    nan_estimates: int  # not finite: the service drops them, never sent
    stale: int  # published with a capture time not after the previous one
    published: int
    published_clean: int  # the same flight without the fault
    beyond_3_sigma: int
    beyond_3_sigma_clean: int
    worst_error_m: float
    worst_sigmas: float
    resets: int
    recovery_s: float | None  # None: the fault ended before publication started
    reboots_seen: int = 0  # 'autopilot rebooted' (origin resent), right only for a reboot
    ignored: dict = field(default_factory=dict)

    @property
    def beyond_share(self) -> float:
        return self.beyond_3_sigma / max(self.published, 1)


class Intake:
    """The service's receiving side without its event loop: codec -> watch -> estimator."""

    def __init__(self, estimator: FusionEstimator, filtered: bool = True):
        self.estimator = estimator
        self.filtered = filtered
        self.watch = AutopilotWatch(HEARTBEAT_TIMEOUT_S, own=(1, 197))
        self.codec = MavlinkCodec(1, 197, lambda data: True, self._on_message)
        self.now = 0.0
        self.errors: Counter[str] = Counter()
        self.events: Counter[str] = Counter()  # the watch's: connected, rebooted, ...

    def feed(self, packet: Packet) -> None:
        self.now = packet.arrival
        try:
            self.codec.feed(packet.data)
        except Exception as exc:  # the service's link would carry on; count it
            self.errors[f"intake {type(exc).__name__}: {exc}"[:120]] += 1

    def _on_message(self, msg: object) -> None:
        if not self.filtered:  # the watch only looks (events), as before it filtered
            self.events.update(str(e) for e in self.watch.on_message(msg, self.now))
            self.estimator.on_autopilot_message(msg)
            return
        verdict = self.watch.receive(msg, self.now)
        self.events.update(str(e) for e in verdict.events)
        if verdict.accepted:
            self.estimator.on_autopilot_message(msg)


def run_stream(stream: Stream, filtered: bool = True) -> Outcome:
    """Packets and frames in arrival order through the intake and a fresh estimator."""
    clock = [0.0]
    estimator = FusionEstimator(fusion_sim.fusion_config(), MountingConfig(),
                                now=lambda: clock[0])
    intake = Intake(estimator, filtered)
    packets, k, out = stream.packets, 0, []
    for ready, result, t_capture in stream.flight.frames:
        while k < len(packets) and packets[k].arrival <= ready:
            clock[0] = packets[k].arrival
            intake.feed(packets[k])
            k += 1
        clock[0] = ready
        try:
            out.append((t_capture, estimator.on_frame(result, t_capture)))
        except Exception as exc:  # the tracking thread would skip the frame's estimate
            intake.errors[f"estimator {type(exc).__name__}: {exc}"[:120]] += 1
            out.append((t_capture, None))
    return Outcome(out, intake.errors, {str(k): v for k, v in intake.watch.ignored.items()},
                   intake.events["rebooted"])


def published(outcome: Outcome) -> tuple[list[tuple[float, object]], int, int]:
    """What the service would send (finite, capture times increasing), and how many were
    dropped for NaN/infinity and for stale or repeated stamps."""
    sent, nan, stale, last = [], 0, 0, -np.inf
    for t_capture, e in outcome.estimates:
        if e is None:
            continue
        if not_finite(e):
            nan += 1
        elif t_capture <= last:
            stale += 1
        else:
            sent.append((t_capture, e))
            last = t_capture
    return sent, nan, stale


def position_errors(flight: fusion_sim.Flight, sent: list[tuple[float, object]]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flight times, position errors (N, 3) and reported stds (N, 3) of the published poses,
    from the first one on, in the autopilot's heading frame."""
    if not sent:
        return np.empty(0), np.empty((0, 3)), np.empty((0, 3))
    truth = flight.truth
    first_t, first = sent[0]
    start = truth.p[truth.at(first_t - fusion_sim.BOOT_OFFSET)]
    times = np.array([t - fusion_sim.BOOT_OFFSET for t, _ in sent])
    moved = np.array([truth.p[truth.at(t)] - start for t in times])
    moved = turned_about_down(moved, flight.compass_bias_deg)
    err = np.array([e.position - first.position for _, e in sent]) - moved
    std = np.sqrt(np.array([np.clip(np.diag(e.pose_covariance)[:3], 0.0, None)
                            for _, e in sent]))
    return times, err, std


def recovery_time(times: np.ndarray, ok: np.ndarray, fault_end: float) -> float:
    """Seconds from the fault's end to the first position within 3 sigma that starts
    RECOVERED_FOR_S of publication without gaps and with RECOVERED_SHARE within 3 sigma; inf
    when that never comes."""
    after = np.flatnonzero((times >= fault_end) & ok)
    for i in after:
        window = (times >= times[i]) & (times <= times[i] + RECOVERED_FOR_S)
        span = times[window]
        if span[-1] - span[0] < RECOVERED_FOR_S - MAX_GAP_S:
            continue
        gaps_ok = np.all(np.diff(span) <= MAX_GAP_S) if len(span) > 1 else False
        if gaps_ok and np.mean(ok[window]) >= RECOVERED_SHARE:
            return float(times[i] - fault_end)
    return float("inf")


def score(name: str, stream: Stream, outcome: Outcome, clean: Outcome) -> FaultScore:
    """The scenario's FaultScore against the same flight without the fault (`clean`)."""
    sent, nan, stale = published(outcome)
    times, err, std = position_errors(stream.flight, sent)
    with np.errstate(divide="ignore", invalid="ignore"):
        sigmas = np.where(std > 0, np.abs(err) / std, np.where(np.abs(err) > 1e-9, np.inf, 0))
    worst = sigmas.max(axis=1) if len(sent) else np.empty(0)
    ok = worst <= SIGMAS
    counters = [e.reset_counter for _, e in sent]
    resets = int(np.count_nonzero(np.diff(counters))) if counters else 0
    clean_sent, _, _ = published(clean)
    _, clean_err, clean_std = position_errors(stream.flight, clean_sent)
    started = bool(sent) and times[0] < stream.fault[1]
    return FaultScore(
        name, stream.injected, sum(outcome.errors.values()), nan, stale, len(sent),
        len(clean_sent), int(np.count_nonzero(~ok)),
        int(np.count_nonzero(np.any(np.abs(clean_err) > SIGMAS * clean_std, axis=1))),
        float(np.linalg.norm(err, axis=1).max()) if len(sent) else 0.0,
        float(worst.max()) if len(sent) else 0.0, resets,
        recovery_time(times, ok, stream.fault[1]) if started else None, outcome.reboots,
        outcome.ignored)
