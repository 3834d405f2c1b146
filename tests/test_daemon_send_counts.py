"""What the service counts as sent: an estimate goes out only when the link takes its vision
message; before the link is open (or once it is gone) it is counted as skipped, and the next
estimate is sent when the link takes it."""

from __future__ import annotations

import time

import numpy as np
from daemon_helpers import FakeTracker, service_config

from daemon.camera import TestPatternSource
from daemon.estimate import PassThroughEstimator
from daemon.service import Service
from daemon.tracking import TrackedFrame


def test_estimates_the_link_does_not_take_are_not_counted_as_sent():
    cfg = service_config("udpout:127.0.0.1:9", fusion={"enabled": False})
    estimator = PassThroughEstimator(cfg.mounting, cfg.mavlink)
    service = Service(cfg, TestPatternSource(64, 48, 30.0), lambda frame: FakeTracker(),
                      estimator=estimator)
    link_open = [False]
    taken: list[object] = []
    service.codec.send = lambda msg: link_open[0] and (taken.append(msg) or True)
    service.tracking = type("Tracking", (), {"gate": type("Gate", (), {
        "done": staticmethod(lambda t: None)})()})()
    tracker, t0 = FakeTracker(), time.monotonic()  # fresh captures: none stale
    offered = {False: 0, True: 0}  # estimates offered while the link was closed / open
    for k in range(6):
        t = t0 + k / 30
        link_open[0] = k >= 3
        result = tracker.process(np.zeros((48, 64), np.uint8), t)
        estimate = estimator.on_frame(result, t)
        offered[link_open[0]] += estimate is not None
        service._on_tracked(TrackedFrame(k, t, t, result, estimate, t, 0.0, t))
    assert offered[False] >= 1 and offered[True] >= 2
    assert service.stats.skipped_no_link == offered[False]
    assert service.stats.sent == len(taken) == offered[True]
