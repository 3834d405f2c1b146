"""Frames a busy companion's service drops, for the virtual-clock loop (`sdvl fly
--drop-frames`): the real-time service tracks the newest frame and drops those that came while
it was busy, so a loaded machine drops them in runs (fly-realtime-loaded in RESULTS.md: 22.8 %
of the frames, gaps up to 366 ms). Here the runs are seeded: each begins with the probability
that gives `share` on average and lasts MEAN_RUN frames on average (geometric).
"""

from __future__ import annotations

import numpy as np

MEAN_RUN = 3.0  # frames; not measured on a companion yet (the loaded runs logged no run lengths)


class FrameDrops:
    """Which frames the service drops, frame by frame (`drop()`), the same for a seed."""

    def __init__(self, share: float, seed: int):
        if not 0.0 <= share < 1.0:
            raise ValueError(f"a share of frames dropped is in [0, 1), not {share}")
        self.share = share
        self.stay = 1.0 - 1.0 / MEAN_RUN  # a run goes on
        self.enter = share / MEAN_RUN / (1.0 - share)  # a run starts: `share` dropped in all
        self.rng = np.random.default_rng([seed, 0xD209])
        self.dropping = False
        self.dropped = 0

    def drop(self) -> bool:
        """Whether the next frame is dropped."""
        if self.share == 0.0:
            return False
        self.dropping = bool(self.rng.random() < (self.stay if self.dropping else self.enter))
        self.dropped += self.dropping
        return self.dropping
