"""Events of a synthetic flight: people walking through the view, the lens covered for a
while (blackout) and a jump in the video (kidnap: no frames for a while the drone moves)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.synth.scene import Walker


@dataclass(frozen=True)
class Interval:
    """[start, end) seconds."""

    start: float
    end: float

    def contains(self, t: float | np.ndarray):
        """True where t is inside."""
        return (t >= self.start) & (t < self.end)


def walkers_across(center, radius: float, count: int, duration: float, texture: int,
                   rng: np.random.Generator, speed: float = 1.4,
                   pause: float = 0.0) -> list[Walker]:
    """`count` people-sized boxes crossing a disc of `radius` m around `center` (x, y) at
    walking speed, each entering at a random time of the flight; with `pause`, each stops
    for up to that many seconds somewhere along its way."""
    out = []
    for k in range(count):
        heading = rng.uniform(0, 2 * np.pi)
        direction = np.array([np.cos(heading), np.sin(heading)])
        offset = rng.uniform(-0.6, 0.6) * radius * np.array([-direction[1], direction[0]])
        start = np.asarray(center[:2], float) + offset - direction * radius
        v = direction * speed * rng.uniform(0.7, 1.3)
        stop = rng.uniform(0.5, 1.0) * pause
        t0 = rng.uniform(0.0, max(duration - 2 * radius / speed - stop, 0.1))
        out.append(Walker(start, v, t0, texture, 0.004, int(rng.integers(1 << 30)) + k,
                          pause_after=rng.uniform(0.3, 1.7) * radius / speed, pause=stop))
    return out


def crowd_leaving(center, count: int, spread, leave: float, heading: float,
                  texture: int, rng: np.random.Generator, speed: float = 1.2) -> list[Walker]:
    """`count` people standing in a group about `spread` (dx, dy) m wide around `center` from
    the start of the flight, who walk off together at about `leave` s (within a second of each
    other), heading about `heading` rad (+-20 degrees), at walking speed."""
    out = []
    spots = _spread_out(np.asarray(spread, float), count, 0.8, rng)
    for k, spot in enumerate(spots):
        h = heading + rng.uniform(-0.35, 0.35)
        v = np.array([np.cos(h), np.sin(h)]) * speed * rng.uniform(0.8, 1.2)
        height = rng.uniform(1.6, 1.85)
        out.append(Walker(np.asarray(center[:2], float) + spot, v, 0.0, texture, 0.004,
                          int(rng.integers(1 << 30)) + k, size=(0.5, 0.3, height),
                          pause=leave + rng.uniform(0.0, 1.0)))
    return out


def _spread_out(spread: np.ndarray, count: int, min_gap: float,
                rng: np.random.Generator) -> np.ndarray:
    """`count` random spots in a `spread` (dx, dy) box centred on 0, at least `min_gap` m
    apart where possible (people keep their distance)."""
    spots: list[np.ndarray] = []
    for _ in range(50 * count):
        if len(spots) == count:
            break
        p = (rng.random(2) - 0.5) * spread
        if all(np.linalg.norm(p - q) >= min_gap for q in spots):
            spots.append(p)
    while len(spots) < count:
        spots.append((rng.random(2) - 0.5) * spread)
    return np.array(spots)


def frame_times(duration: float, fps: float, gaps: tuple[Interval, ...]) -> np.ndarray:
    """Frame timestamps at `fps` over the flight, none inside the gaps (kidnaps)."""
    t = np.arange(int(np.floor(duration * fps + 1e-9)) + 1) / fps
    keep = np.ones(t.size, bool)
    for gap in gaps:
        keep &= ~gap.contains(t)
    return t[keep]
