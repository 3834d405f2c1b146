"""When the current map is aligned: its scale and heading have converged.

The filter's standard deviations of ln(scale) (relative scale error) and of the heading part of
the alignment are compared with the configured limits. Publication starts once both have been
below them for `min_aligned_s` and stops again only when one exceeds twice its limit (a new map
resets both). Progress goes to the log and to a `report(text)` callback (STATUSTEXT).
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Callable

import numpy as np

from daemon.fusion.config import FusionConfig
from daemon.fusion.state import HEADING, LOG_SCALE, NavFilter

log = logging.getLogger("sdvl.fusion")


class Alignment(enum.Enum):
    """Whether the current map's scale and heading are known well enough to publish."""

    ALIGNING = "aligning"  # not yet, or lost again (a spread above twice its limit)
    ALIGNED = "aligned"  # both spreads below their limits for min_aligned_s


class AlignmentGate:
    """Tracks convergence of the current segment and reports progress."""

    def __init__(self, cfg: FusionConfig, report: Callable[[str], None] | None = None):
        self.cfg = cfg
        self.report = report
        self.aligned_since: float | None = None
        self.state = Alignment.ALIGNING
        self.last_text_t = float("-inf")
        self.last_text = ""

    def spreads(self, f: NavFilter) -> tuple[float, float]:
        """(relative scale std, heading std in degrees, including the compass bias)."""
        P = f.P
        heading_var = max(P[HEADING, HEADING], 0.0) + np.radians(self.cfg.heading_bias_std_deg)**2
        return (float(np.sqrt(max(P[LOG_SCALE, LOG_SCALE], 0.0))),
                float(np.degrees(np.sqrt(heading_var))))

    def update(self, f: NavFilter, t: float) -> bool:
        """True when the map is aligned at time t."""
        cfg = self.cfg
        scale_std, heading_std = self.spreads(f)
        if not (math.isfinite(scale_std) and math.isfinite(heading_std)):
            scale_std = heading_std = math.inf
        good = scale_std <= cfg.scale_std_max and heading_std <= cfg.heading_std_max_deg
        lost = scale_std > 2 * cfg.scale_std_max or heading_std > 2 * cfg.heading_std_max_deg
        if good and self.aligned_since is None:
            self.aligned_since = t
        elif lost:
            self.aligned_since = None
        was = self.state
        self.state = (Alignment.ALIGNED if self.aligned_since is not None
                      and t - self.aligned_since >= cfg.min_aligned_s else Alignment.ALIGNING)
        if self.state is was is Alignment.ALIGNING:
            self._say(f"aligning: scale +-{100 * min(scale_std, 9.99):.0f}%, heading "
                      f"+-{min(heading_std, 999):.1f} deg", t)
        elif self.state is Alignment.ALIGNED and was is Alignment.ALIGNING:
            self._say(f"aligned: scale {f.scale:.3g} m/unit", t, force=True)
        elif self.state is Alignment.ALIGNING:
            self._say("alignment lost, re-aligning", t, force=True)
        return self.state is Alignment.ALIGNED

    def waiting(self, reason: str, t: float) -> None:
        """Report why alignment cannot start (e.g. no attitude from the autopilot)."""
        self._say(reason, t)

    def restart(self) -> None:
        """A new map segment: alignment starts over."""
        self.aligned_since = None

    def _say(self, text: str, t: float, force: bool = False) -> None:
        if not force and (text == self.last_text
                          or t - self.last_text_t < self.cfg.progress_interval_s):
            return
        self.last_text, self.last_text_t = text, t
        log.info("fusion: %s", text)
        if self.report is not None:
            self.report(text)
