"""Shared pieces of the daemon tests: a deterministic fake tracker that follows the vo.tracker
contract, and a service wired to a simulated autopilot, run on a background event loop."""

from __future__ import annotations

import asyncio
import threading
import time

import numpy as np

from daemon.camera import TestPatternSource
from daemon.config import Config, replace
from daemon.service import Service
from vo.result import FrameResult

SPEED = np.array([0.3, -0.1, 0.2])  # camera velocity in the tracker's world frame, units/s


class FakeTracker:
    """Camera moving at SPEED with a slow yaw; `script(index) -> (quality, new_segment)`."""

    def __init__(self, script=None):
        self.script = script or (lambda i: ("good", i == 0))
        self.index = 0
        self.t0: float | None = None
        self.closed = False

    def pose(self, t: float) -> np.ndarray:
        T = np.eye(4)
        a = 0.1 * t
        T[:3, :3] = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        T[:3, 3] = SPEED * t
        return T

    def process(self, image: np.ndarray, t: float, **extra) -> FrameResult:
        assert image.dtype == np.uint8 and image.ndim == 2
        self.t0 = t if self.t0 is None else self.t0
        quality, new_segment = self.script(self.index)
        self.index += 1
        pose = None if quality in ("lost", "initializing") else self.pose(t - self.t0)
        cov = np.diag([1e-4] * 3 + [1e-5] * 3) if pose is not None else None
        return FrameResult(t, pose, quality, covariance=cov, n_matches=100, n_attempts=120,
                           n_inliers=90, timings={"total": 0.001}, new_segment=new_segment)

    def close(self) -> None:
        self.closed = True


def service_config(link: str, **sections: dict) -> Config:
    """A service config for tests: test pattern camera, the given link, pass-through estimator
    (the link is tested with a fake tracker; the EKF path has its own tests)."""
    base = replace(Config(), camera={"source": "testpattern", "width": 64, "height": 48},
                   mavlink={"link": link, "heartbeat_timeout_s": 0.6,
                            "statustext_interval_s": 0.2},
                   mounting={"preset": "forward"}, fusion={"enabled": False})
    return replace(base, **sections)


class RunningService:
    """A Service on its own event loop thread; `stop()` returns its exit code."""

    def __init__(self, config: Config, tracker: FakeTracker | None = None, source=None,
                 make_tracker=None, **kwargs):
        self.tracker = tracker or FakeTracker()
        cam = config.camera
        self.source = source or TestPatternSource(cam.width, cam.height, cam.fps)
        self.service = Service(config, self.source, make_tracker or (lambda frame: self.tracker),
                               **kwargs)
        self.loop = asyncio.new_event_loop()
        self.exit_code: int | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        self.exit_code = self.loop.run_until_complete(self.service.run())
        self.loop.close()

    def call(self, fn, *args):
        """Run fn(*args) on the service loop and return its result."""
        future = asyncio.run_coroutine_threadsafe(_call(fn, *args), self.loop)
        return future.result(5)

    def stop(self, timeout: float = 3.0) -> int | None:
        start = time.monotonic()
        if self.thread.is_alive():
            self.loop.call_soon_threadsafe(self.service.stop)
        self.thread.join(timeout)
        self.stop_seconds = time.monotonic() - start
        return self.exit_code


# a busy machine runs the service slower: waiting longer costs nothing once the condition holds
BUSY_SLACK = 4.0


async def _call(fn, *args):
    return fn(*args)


def wait_for(predicate, timeout: float = 10.0, step: float = 0.02) -> bool:
    """Poll until predicate() is true; False after `timeout` times BUSY_SLACK seconds."""
    deadline = time.monotonic() + timeout * BUSY_SLACK
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()
