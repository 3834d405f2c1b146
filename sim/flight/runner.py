"""Flies a Mission as a user's ground-station script does: one step at a time, each a MAVLink
command and a wait for the autopilot's answer (COMMAND_ACK, HEARTBEAT, STATUSTEXT,
LOCAL_POSITION_NED, EKF_STATUS_REPORT), abandoned at the step's timeout or when the autopilot
changes mode by itself (a failsafe). What happened is kept per step for the report.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2

from sim.flight.gcs import GroundStation
from sim.flight.mission import COPTER_MODES, Action, Mission, Step, WaitFor

POLL_S = 0.25  # LOCAL_POSITION_NED / EKF_STATUS_REPORT asked for this often while waited on
RETRY_S = 1.0  # a refused arming is tried again this often until the step's timeout
TAKEOFF_REACHED = 0.95  # of the take-off height, by the autopilot's estimate (as scripts do)
ARRIVED_SPEED_M_S = 0.2  # a goto has arrived when also this slow
VISION_MIN_HZ = 10.0  # the companion's messages at least this often: 'vision' is there


class Outcome(Enum):
    """How a step ended."""

    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    TIMEOUT = "timed out"


@dataclass
class StepResult:
    """One step as flown: when it ran, how it ended and why; `target` is a goto's point and
    `home` the autopilot's position at arming, both in its local NED frame."""

    step: Step
    started: float
    ended: float | None = None
    outcome: Outcome = Outcome.RUNNING
    detail: str = ""
    target: np.ndarray | None = None
    home: np.ndarray | None = None
    arrived: float | None = None  # goto: when the autopilot's estimate got there


@dataclass
class _Progress:
    """Per-step working state: when its command went out, when it last polled, since when its
    texts count, the mode it asked for."""

    sent: float = -np.inf
    polled: float = -np.inf
    texts_from: float = 0.0
    requested: int | None = None


class MissionRunner:
    """`tick(now)` as often as the link is served; `done` when the mission has ended."""

    def __init__(self, mission: Mission, gcs: GroundStation,
                 on_step: Callable[[str], None] | None = None):
        self.mission = mission
        self.gcs = gcs
        self.on_step = on_step  # told a line as each step starts (progress)
        self.results: list[StepResult] = []
        self.home: np.ndarray | None = None
        self.height_m = 0.0  # the height goto points without one fly at (above home)
        self._progress = _Progress()
        self._expected_mode: int | None = None

    @property
    def done(self) -> bool:
        finished = len(self.results) == len(self.mission.steps) and \
            self.results[-1].outcome is not Outcome.RUNNING
        return finished or self.failed is not None

    @property
    def failed(self) -> StepResult | None:
        return next((r for r in self.results if r.outcome in (Outcome.FAILED, Outcome.TIMEOUT)),
                    None)

    def tick(self, now: float) -> None:
        """Advance the current step (start the next one when it is done)."""
        self.gcs.tick(now)
        if self.done:
            return
        if not self.results or self.results[-1].outcome is Outcome.DONE:
            step = self.mission.steps[len(self.results)]
            self.results.append(StepResult(step, now, home=self.home))
            self._progress = _Progress(texts_from=now)
            if self.on_step is not None:
                self.on_step(f"{now:6.1f} s  step {step.index}/{len(self.mission.steps)} "
                             f"{step.describe()}")
        current = self.results[-1]
        if self._mode_taken_away(current, now):
            return
        outcome, detail = HANDLERS[current.step.action](self, current, now)
        if outcome is Outcome.RUNNING and current.step.timeout_s is not None and \
                now - current.started > current.step.timeout_s:
            texts = "; ".join(self.gcs.texts_since(self._progress.texts_from)[-3:])
            outcome, detail = Outcome.TIMEOUT, detail + (f" ({texts})" if texts else "")
        if outcome is not Outcome.RUNNING:
            current.outcome, current.detail, current.ended = outcome, detail, now

    def _mode_taken_away(self, current: StepResult, now: float) -> bool:
        """The autopilot left the mode we set by itself (a failsafe): the mission ends."""
        mode = self.gcs.custom_mode
        if self._expected_mode is None or mode is None or \
                mode in (self._expected_mode, self._progress.requested):
            return False
        name = next((n for n, v in COPTER_MODES.items() if v == mode), str(mode))
        texts = "; ".join(self.gcs.texts_since(current.started - 1.0)[-3:])
        current.outcome, current.ended = Outcome.FAILED, now
        current.detail = f"the autopilot switched to {name} by itself" + \
            (f": {texts}" if texts else "")
        return True

    # --- step handlers: (outcome, detail) --------------------------------------------------

    def _poll(self, message_id: int, now: float) -> None:
        if now - self._progress.polled >= POLL_S:
            self._progress.polled = now
            self.gcs.request(message_id)

    def _wait(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        gcs, what = self.gcs, r.step.value
        if what is WaitFor.AUTOPILOT:
            ok = gcs.heartbeat_t is not None and gcs.system_status != mavlink2.MAV_STATE_BOOT
        elif what is WaitFor.VISION:
            ok = gcs.vision_rate(now) >= VISION_MIN_HZ
        elif what is WaitFor.POSITION:
            self._poll(ardupilotmega.MAVLINK_MSG_ID_EKF_STATUS_REPORT, now)
            ok = gcs.has_position()
        else:
            texts = gcs.texts_since(0.0, mavlink2.MAV_SEVERITY_DEBUG)
            ok = any("using external nav" in t for t in texts)
        return (Outcome.DONE, "") if ok else (Outcome.RUNNING, f"no {what.value} yet")

    def _mode(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        number = COPTER_MODES[r.step.value]
        if self._progress.sent == -np.inf:
            self._request_mode(number, now)
        result = self.gcs.ack(mavlink2.MAV_CMD_DO_SET_MODE, r.started)
        if result is not None and result != mavlink2.MAV_RESULT_ACCEPTED:
            return Outcome.FAILED, self._refusal("mode change refused", r)
        if result is not None and self.gcs.custom_mode == number:
            self._expected_mode = number
            return Outcome.DONE, ""
        return Outcome.RUNNING, "no answer"

    def _request_mode(self, number: int, now: float) -> None:
        """DO_SET_MODE; until the autopilot confirms, either mode is ours."""
        self._progress.sent = now
        self._progress.requested = number
        self.gcs.set_mode(number)

    def _refusal(self, what: str, r: StepResult) -> str:
        texts = self.gcs.texts_since(r.started)
        return f"{what}: {'; '.join(dict.fromkeys(texts))}" if texts else what

    def _arm(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        gcs = self.gcs
        self._poll(mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, now)
        if gcs.armed and gcs.position is not None:
            self.home = r.home = gcs.position.position.copy()
            return Outcome.DONE, ""
        if not gcs.armed and now - self._progress.sent >= RETRY_S:
            self._progress.sent = now
            gcs.arm()
        return Outcome.RUNNING, self._refusal("arming refused", r)

    def _takeoff(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        height = float(r.step.value)
        if self._progress.sent == -np.inf:
            self._progress.sent = now
            self.gcs.takeoff(height)
            self.height_m = height
        result = self.gcs.ack(mavlink2.MAV_CMD_NAV_TAKEOFF, r.started)
        if result is not None and result != mavlink2.MAV_RESULT_ACCEPTED:
            return Outcome.FAILED, self._refusal("take-off refused", r)
        self._poll(mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, now)
        position = self.gcs.position
        climbed = (self.home[2] - position.position[2]
                   if position is not None and self.home is not None else 0.0)
        if climbed >= TAKEOFF_REACHED * height:
            return Outcome.DONE, ""
        return Outcome.RUNNING, f"at {climbed:.1f} of {height:g} m"

    def _hold(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        return (Outcome.DONE, "") if now - r.started >= float(r.step.value) else \
            (Outcome.RUNNING, "")

    def _goto(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        step = r.step
        if r.target is None:
            north, east, height = step.value
            self.height_m = self.height_m if height is None else height
            home = self.home if self.home is not None else np.zeros(3)
            r.target = home + np.array([north, east, -self.height_m])
            self.gcs.go_to(r.target, now)
        self._poll(mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, now)
        position = self.gcs.position
        if r.arrived is None and position is not None and position.t >= r.started and \
                np.linalg.norm(position.position - r.target) <= step.tolerance_m and \
                np.linalg.norm(position.velocity) <= ARRIVED_SPEED_M_S:
            r.arrived = now
        if r.arrived is not None and now - r.arrived >= step.settle_s:
            return Outcome.DONE, ""
        off = "no position" if position is None else \
            f"{np.linalg.norm(position.position - r.target):.2f} m off"
        return Outcome.RUNNING, off

    def _land(self, r: StepResult, now: float) -> tuple[Outcome, str]:
        land = COPTER_MODES["LAND"]
        if self._progress.sent == -np.inf:
            self._request_mode(land, now)
        result = self.gcs.ack(mavlink2.MAV_CMD_DO_SET_MODE, r.started)
        if result is not None and result != mavlink2.MAV_RESULT_ACCEPTED:
            return Outcome.FAILED, self._refusal("LAND refused", r)
        if self.gcs.custom_mode == land:
            self._expected_mode = land
        if result is not None and not self.gcs.armed:
            return Outcome.DONE, ""
        return Outcome.RUNNING, "still armed"


HANDLERS = {Action.WAIT: MissionRunner._wait, Action.MODE: MissionRunner._mode,
            Action.ARM: MissionRunner._arm, Action.TAKEOFF: MissionRunner._takeoff,
            Action.HOLD: MissionRunner._hold, Action.GOTO: MissionRunner._goto,
            Action.LAND: MissionRunner._land}


def step_printer(prefix: str) -> Callable[[str], None]:
    """A MissionRunner `on_step` that prints each step's line on stderr with the wall time."""
    start = time.monotonic()

    def show(line: str) -> None:
        print(f"{prefix}: {line}  ({time.monotonic() - start:.0f} s)", file=sys.stderr,
              flush=True)
    return show
