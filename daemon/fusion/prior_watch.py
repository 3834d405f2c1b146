"""Says when the tracker keeps refusing the autopilot's attitude as its rotation prior.

The tracker refuses the prior in a frame whose image alignment turned beyond a gate from it
(vo.rotation_prior): now and then in a fast turn, but in most frames only when the camera's turn
is not the attitude's turn through the mounting (a camera mounted other than [mounting] says)
or the clocks disagree. The tracker goes on without the prior in those frames; the user has to
be told what to fix.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from vo.result import PriorUse

WINDOW = 30  # frames that had a prior, about a second of camera
SAY_EVERY_S = 60.0


class PriorWatch:
    """Counts refusals over the last WINDOW frames with a prior; says so (at most once a
    minute) when more than half were refused."""

    def __init__(self, report: Callable[[str], None] | None):
        self.report = report
        self.recent: deque[bool] = deque(maxlen=WINDOW)  # refused?
        self.refused = 0
        self._said_t = -float("inf")

    def add(self, use: PriorUse, t: float) -> None:
        """One tracked frame's use of the prior at time t."""
        if use == PriorUse.NONE:
            return
        refused = use == PriorUse.REFUSED
        self.refused += refused
        self.recent.append(refused)
        if (len(self.recent) == WINDOW and 2 * sum(self.recent) > WINDOW
                and t - self._said_t >= SAY_EVERY_S and self.report is not None):
            self._said_t = t
            self.report(f"the camera's turns disagree with the autopilot's attitude in "
                        f"{sum(self.recent)} of the last {WINDOW} frames: check [mounting] "
                        "(how the camera is turned on the body); tracking goes on without "
                        "the attitude")
