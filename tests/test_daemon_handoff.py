"""The tracker's mapping thread waits for each frame's handoff to the loop before mapping it
(daemon.tracking.HandoffGate): mapping never competes with the estimate on its way out."""

from __future__ import annotations

import queue
import threading
import time
from types import SimpleNamespace

import numpy as np
from daemon_helpers import FakeTracker, RunningService, service_config, wait_for

from daemon.frames import Frame, LatestSlot
from daemon.tracking import HandoffGate, TrackingThread
from sim.autopilot import SimAutopilot, configured_options


def test_gate_waits_for_its_frame_and_no_longer_than_the_timeout():
    """Released by its frame's handoff (a timeout far longer than the test cannot be what
    released it), not by an earlier frame's; without a handoff, released at the timeout. No
    bound here depends on how fast the machine wakes a thread."""
    gate = HandoffGate(timeout_s=60.0)
    released = []
    waiter = threading.Thread(target=lambda: released.append((gate.wait(SimpleNamespace(t=2.0)),
                                                              time.monotonic())))
    waiter.start()
    time.sleep(0.05)
    gate.done(1.0)  # an earlier frame: keep waiting
    time.sleep(0.05)
    assert not released
    t_done = time.monotonic()
    gate.done(2.5)  # this frame and later ones
    waiter.join(30.0)
    assert released and 0 <= released[0][1] - t_done < 30.0
    start = time.monotonic()
    HandoffGate(timeout_s=0.3).wait(SimpleNamespace(t=9.0))  # never handed off: bounded
    assert 0.28 < time.monotonic() - start < 30.0


class _Mapper:
    def __init__(self):
        self.before_step = lambda frame: None


class MappingFakeTracker(FakeTracker):
    """A threaded tracker stand-in: every processed frame goes to its own mapping thread,
    which records when each step starts; a new map (frame 15) brings a new mapper."""

    threaded = True

    def __init__(self):
        super().__init__()
        self.mapper = _Mapper()
        self.steps: list[tuple[float, float]] = []
        self._queue: queue.Queue = queue.Queue()
        threading.Thread(target=self._mapping, daemon=True).start()

    def process(self, image, t, **extra):
        if self.index == 15:
            self.mapper = _Mapper()
        result = super().process(image, t)
        self._queue.put(SimpleNamespace(t=t))
        return result

    def _mapping(self):
        while True:
            frame = self._queue.get()
            self.mapper.before_step(frame)
            self.steps.append((frame.t, time.monotonic()))


class _PatientGate(HandoffGate):
    """The service's gate with a timeout no busy machine reaches, recording how each wait
    ended: the order is what is tested, not how fast the loop hands a frame off."""

    def __init__(self):
        super().__init__(timeout_s=60.0)
        self.released_by_handoff: list[bool] = []

    def wait(self, frame: object) -> bool:
        released = super().wait(frame)
        self.released_by_handoff.append(released)
        return released


def test_service_releases_each_mapping_step_after_the_frame_was_handled(monkeypatch):
    handled: dict[float, float] = {}
    gates: list[_PatientGate] = []

    def patient_gate() -> _PatientGate:
        gates.append(_PatientGate())
        return gates[-1]

    monkeypatch.setattr("daemon.tracking.HandoffGate", patient_gate)
    tracker = MappingFakeTracker()
    with SimAutopilot(configured_options()) as sim:
        run = RunningService(service_config(sim.url), tracker=tracker,
                             on_tracked=lambda tf, sent: handled.setdefault(tf.t_source,
                                                                            time.monotonic()))
        assert wait_for(lambda: len(tracker.steps) >= 40, 10.0)
        assert run.stop() == 0
    # the first step of each mapper (the first frame, the first of the new map) runs before
    # the tracking thread has seen that mapper; every other one waits for its handoff
    steps = [step for k, step in enumerate(tracker.steps) if k not in (0, 15)]
    early = [t for t, started in steps if t not in handled or started < handled[t]]
    assert early == []
    assert len(gates) == 1 and len(gates[0].released_by_handoff) >= len(steps)
    assert all(gates[0].released_by_handoff)  # none released by the timeout


class _SlowMappingTracker(FakeTracker):
    """A tracker stand-in whose mapping backlog is full until `room` is set."""

    def __init__(self):
        super().__init__()
        self.room = threading.Event()
        self.seen: list[int] = []

    def wait_for_mapping(self, timeout=None):
        return self.room.wait(timeout)

    def process(self, image, t, **extra):
        self.seen.append(int(t))
        return super().process(image, t)


def test_tracking_takes_the_newest_frame_once_mapping_has_room():
    """A slow mapper holds tracking before it takes a frame: the camera's frames meanwhile
    replace each other in the slot (skipped whole), and the one tracked is the newest."""
    slot, tracker, delivered = LatestSlot(), _SlowMappingTracker(), []
    estimator = SimpleNamespace(on_frame=lambda result, t_capture: None,
                                orientation=lambda t_capture: None)
    thread = TrackingThread(slot, lambda frame: tracker, estimator, delivered.append,
                            lambda: None)
    thread.tracker = tracker
    thread.start()
    image = np.zeros((8, 8), np.uint8)
    for k in range(5):
        slot.put(Frame(k, float(k), 0.0, image))
    time.sleep(0.15)
    assert tracker.seen == []
    tracker.room.set()
    assert wait_for(lambda: tracker.seen == [4], 2.0)
    assert slot.dropped == 4
    thread.stop()
    slot.close()
    thread.join(2.0)
