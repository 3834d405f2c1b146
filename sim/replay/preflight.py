"""The pre-flight of a replayed drone flight: before the recorded flight the vehicle stands
powered on at its start pose for a few seconds, the camera sees that first view, the service
starts sending and the pilot arms (pilot.py), as a real flight starts. The autopilot's VisOdom
pre-arm check needs our messages before take-off; a replay that starts in the air would never
show whether it gets them."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from sim.trajectory import Trajectory

PREFLIGHT_S = 5.0


def held_before(trajectory: Trajectory, seconds: float) -> Trajectory:
    """The trajectory with its first pose held for `seconds` before it (the vehicle standing
    still through the pre-flight; a second more against rounding of the frame times), for
    scoring what was sent then."""
    t0 = trajectory.t[0]
    step = float(np.median(np.diff(trajectory.t))) if len(trajectory) > 1 else 0.1
    before = np.arange(t0 - seconds - 1.0, t0 - 0.5 * step, step)
    n = len(before)
    return Trajectory(np.concatenate([before, trajectory.t]),
                      np.vstack([np.repeat(trajectory.positions[:1], n, 0), trajectory.positions]),
                      np.vstack([np.repeat(trajectory.quaternions[:1], n, 0),
                                 trajectory.quaternions]))


@dataclass
class WithPreflight:
    """The frames of `flight` (a harness.FirstFrames) with `seconds` of its first frame, at the
    frame rate, before them."""

    flight: object
    seconds: float = PREFLIGHT_S

    @property
    def name(self) -> str:
        return self.flight.name

    @property
    def camera(self) -> object:
        return self.flight.camera

    @property
    def period(self) -> float:
        """The sequence's frame period, s."""
        times = np.asarray(self.flight.sequence.timestamps, float)
        return float(np.median(np.diff(times))) if len(times) > 1 else 1.0 / 30.0

    @property
    def count(self) -> int:
        """Frames of the pre-flight."""
        return round(self.seconds / self.period)

    @property
    def start(self) -> float:
        """Sequence time of the flight's first frame."""
        return float(self.flight.sequence.timestamps[0])

    def __len__(self) -> int:
        return len(self.flight) + self.count

    @property
    def has_depth(self) -> bool:
        return self.flight.has_depth

    def depth(self, index: int) -> object:
        """Frame `index`'s depth map: the first frame's through the pre-flight."""
        return self.flight.depth(max(index - self.count, 0))

    def frames(self) -> Iterator[tuple[float, np.ndarray]]:
        """(t, image): the first image at the pre-flight's times, then the flight's frames."""
        frames = iter(self.flight.frames())
        first = next(frames, None)
        if first is None:
            return
        t0, image = first
        for k in range(self.count, 0, -1):
            yield t0 - k * self.period, image
        yield first
        yield from frames
