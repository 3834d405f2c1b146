"""A seeded fuzz of bounded length: simulated flights whose messages are fuzzed (scenarios.py
`fuzz`: fields, stamps, senders, duplicates, drops, swaps, garbage, random messages) until the
wanted number of packets was changed, the scores summed over the flights."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from sim import fusion_sim
from sim.faults.harness import FaultScore, Outcome, run_stream, score
from sim.faults.scenarios import FUZZ_KINDS, changed_in_place, fuzz

SHARES = (0.1, 0.3)  # of the messages fuzzed, alternating between flights
SKIP_S, TAIL_S = 10.0, 8.0  # fuzzed from take-off + SKIP_S to TAIL_S before the end


def fuzz_flight(seed: int, share: float, flight: fusion_sim.Flight | None = None,
                filtered: bool = True, kinds: tuple[str, ...] = FUZZ_KINDS,
                field: tuple[str, str] | None = None) -> FaultScore:
    """One flight (seed) with `share` of its messages fuzzed (with `field` = (message type,
    field name): only that field of that type's messages), scored without a clean run."""
    flight = flight or fusion_sim.simulate(seed=seed)
    window = (SKIP_S, float(flight.truth.t[-1]) - TAIL_S)
    scenario = changed_in_place(share, field=field) if field else fuzz(share, kinds)
    stream = scenario(flight, np.random.default_rng([seed, 28]), window)
    return score(f"fuzz seed {seed}", stream, run_stream(stream, filtered),
                 Outcome([], {}, {}))


def total(scores: list[FaultScore], name: str) -> FaultScore:
    """The scores of several runs as one: counts summed, worst cases and recovery the worst."""
    recoveries = [s.recovery_s for s in scores if s.recovery_s is not None]
    return FaultScore(
        name, *(sum(getattr(s, f) for s in scores) for f in (
            "injected", "crashes", "nan_estimates", "stale", "published", "published_clean",
            "beyond_3_sigma", "beyond_3_sigma_clean")),
        max(s.worst_error_m for s in scores), max(s.worst_sigmas for s in scores),
        sum(s.resets for s in scores), max(recoveries) if recoveries else None,
        sum(s.reboots_seen for s in scores))


def fuzz_packets(packets: int, seed: int, filtered: bool = True,
                 flight: fusion_sim.Flight | None = None, progress: bool = False,
                 kinds: tuple[str, ...] = FUZZ_KINDS,
                 field: tuple[str, str] | None = None) -> FaultScore:
    """Fuzz flights seed, seed+1, ... until `packets` packets were fuzzed with `kinds` (or
    only `field`, fuzz_flight); the summed score (`flight` replaces the simulated survey, e.g.
    a short one for tests); `progress` prints a line per flight on stderr."""
    scores: list[FaultScore] = []
    while sum(s.injected for s in scores) < packets:
        k = len(scores)
        scores.append(fuzz_flight(seed + k, SHARES[k % len(SHARES)], flight, filtered, kinds,
                                  field))
        if progress:
            s = scores[-1]
            print(f"fuzz flight {k + 1}: {sum(x.injected for x in scores)}/{packets} packets; "
                  f"this one: crashes {s.crashes}, beyond 3 sigma {s.beyond_3_sigma}/"
                  f"{s.published}, worst {s.worst_error_m:.1f} m", file=sys.stderr, flush=True)
    name = (f"fuzz {'.'.join(field)}" if field else f"fuzz {len(scores)} flights"
            if kinds == FUZZ_KINDS else f"fuzz {'+'.join(kinds)}")
    return dataclasses.replace(total(scores, name), ignored={"flights": len(scores)})
