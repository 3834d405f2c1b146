"""A test hook: mapping queued as with a mapping thread (a bounded backlog, the map lagging
behind tracking), but each step runs only when the caller says, so that a slow mapping thread
can be emulated deterministically (sim.slow_mapping, `sdvl track --mapping-period`)."""

from __future__ import annotations

from vo.mapping_control import QueuedMapping


class SteppedMapping(QueuedMapping):
    """Queued mapping whose steps the caller runs (run_waiting); a frame that finds the
    backlog full runs the oldest waiting steps itself, as a tracker waits for its thread."""

    def before_frame(self) -> None:
        self.run_waiting(len(self.backlog) - self.backlog.size + 1)

    def run_waiting(self, n: int = 1) -> int:
        """Run the mapping steps of up to n waiting frames, oldest first; how many ran."""
        done = 0
        while done < n and self.backlog.waiting():
            frame, keyframe = self.backlog.take()
            try:
                self.mapper.step(frame, keyframe)
            finally:
                self.backlog.done()
            done += 1
        return done
