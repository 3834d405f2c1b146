"""What the service did with every frame, from its `on_tracked` hook, and timing statistics."""

from __future__ import annotations

import time

import numpy as np

from daemon.tracking import TrackedFrame


class Recorder:
    """Per-frame rows: times (monotonic s), tracking outcome and whether a message went out."""

    def __init__(self) -> None:
        self.rows: list[dict] = []

    def __call__(self, tf: TrackedFrame, sent: bool) -> None:
        now = time.monotonic()
        result = tf.result
        self.rows.append({"t_capture": tf.t_capture, "t_source": tf.t_source,
                          "wait": tf.t_start - tf.t_capture, "track": tf.track_s,
                          "sent": sent, "quality": result.quality,
                          "has_pose": result.has_pose, "new_segment": result.new_segment,
                          "estimate": tf.t_done - tf.t_start - tf.track_s,
                          "handoff": now - tf.t_done,
                          "send": now - tf.t_capture if sent else None})


def stats_ms(values: list[float]) -> dict:
    """median, p95, p99 in milliseconds."""
    a = np.asarray(values, dtype=np.float64) * 1e3
    if a.size == 0:
        return {"n": 0, "median": None, "p95": None, "p99": None}
    return {"n": int(a.size), "median": float(np.median(a)),
            "p95": float(np.percentile(a, 95)), "p99": float(np.percentile(a, 99))}
