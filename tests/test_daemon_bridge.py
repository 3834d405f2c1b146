"""The service's bridge over a stall of the camera or tracker: after BRIDGE_AFTER_S without a
tracked frame's estimate it sends the estimator's carried-forward one, and stops after
BRIDGE_MAX_S so that a longer outage reaches the autopilot's own failsafe."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from daemon_helpers import FakeTracker, service_config

from daemon.camera import TestPatternSource
from daemon.estimate import PassThroughEstimator
from daemon.service import BRIDGE_AFTER_S, BRIDGE_MAX_S, Service
from daemon.tracking import TrackedFrame


class CarryingEstimator(PassThroughEstimator):
    """Its bridge restamps the last estimate (the EKF's own bridge has its tests)."""

    def __init__(self, *args):
        super().__init__(*args)
        self.asked: list[float] = []

    def bridge(self, t):
        self.asked.append(t)
        return None if self._last is None else dataclasses.replace(self._last, t_capture=t)


def test_a_stall_is_bridged_from_its_start_to_its_limit():
    cfg = service_config("udpout:127.0.0.1:9", fusion={"enabled": False})
    estimator = CarryingEstimator(cfg.mounting, cfg.mavlink)
    service = Service(cfg, TestPatternSource(64, 48, 30.0), lambda frame: FakeTracker(),
                      estimator=estimator)
    sent: list[object] = []
    service.codec.send = lambda msg: sent.append(msg) or True  # the transport took it
    service.tracking = type("Tracking", (), {"gate": type("Gate", (), {
        "done": staticmethod(lambda t: None)})()})()
    tracker, now = FakeTracker(), time.monotonic()
    for k, t in enumerate((now - 1 / 30, now)):
        result = tracker.process(np.zeros((48, 64), np.uint8), t)
        service._on_tracked(TrackedFrame(k, t, t, result, estimator.on_frame(result, t), t, 0.0,
                                         t))
    sent.clear()
    assert service.stats.sent == 1 and service.stats.bridged == 0
    service._bridge(now + 0.5 * BRIDGE_AFTER_S)  # a frame late: no bridge yet
    assert estimator.asked == []
    for dt in np.arange(BRIDGE_AFTER_S, BRIDGE_MAX_S, 0.05):
        service._bridge(now + dt)
    assert service.stats.bridged == len(estimator.asked) >= 10
    assert len(sent) == service.stats.bridged  # an ODOMETRY each
    service._bridge(now + BRIDGE_MAX_S + 0.05)  # an outage now: nothing carried on
    assert len(estimator.asked) == service.stats.bridged
