"""The pilot of a replayed flight: on the ground before the flight starts, arms the simulated
autopilot as soon as it lets them, trying once a second as a pilot would (each refusal is the
autopilot's own "PreArm: ..." STATUSTEXT, in its record)."""

from __future__ import annotations

ARM_RETRY_S = 1.0


class Pilot:
    """Arms `autopilot` (a SimAutopilot) during the pre-flight; keeps every attempt."""

    def __init__(self, autopilot: object):
        self.autopilot = autopilot
        self.attempts: list[tuple[float, bool]] = []  # (monotonic time, armed)
        self._next = 0.0

    def tick(self, now: float, on_ground: bool) -> None:
        """Try to arm when due, while on the ground and not yet armed."""
        if not on_ground or self.autopilot.armed or now < self._next:
            return
        self.attempts.append((now, self.autopilot.arm()))
        self._next = now + ARM_RETRY_S
