"""The trackers `sdvl track` and `sdvl track-table` can run (`--method`): monocular SDVL, whose
scale is free (ATE after a Sim(3) alignment), SDVL with depth and the RGB-D SIFT odometry
baseline, which are metric (ATE after an SE(3) alignment) and read each frame's depth map
from the sequence."""

from __future__ import annotations

from pathlib import Path

from sdvl.errors import InputError

# method -> the alignment its trajectory is scored after
METHODS = {"sdvl": "sim3", "sdvl-depth": "se3", "rgbd-sift": "se3"}
SDVL_METHODS = ("sdvl", "sdvl-depth")  # the methods of the SDVL tracker (a TrackerConfig)


def alignment(method: str) -> str:
    """'sim3' for a method with free scale, 'se3' for a metric one."""
    return METHODS[method]


def check_method(method: str, sequence=None) -> None:
    """InputError for an unknown method, or a depth method on a sequence without depth."""
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' (known: {', '.join(METHODS)})")
    if sequence is not None and METHODS[method] == "se3" and not sequence.has_depth:
        raise InputError(f"--method {method} needs depth maps: sequence '{sequence.name}' has "
                         "none (a depth.txt beside its frame list, or a synthetic preset)")


def load_config(method: str, path: Path | None):
    """The method's config: TrackerConfig ([tracker]) for SDVL (with or without depth),
    RgbdConfig ([rgbd]) for the RGB-D odometry; defaults without a file."""
    if method not in SDVL_METHODS:
        from vo.rgbd_odometry import RgbdConfig

        return RgbdConfig.from_toml(path) if path else RgbdConfig()
    from vo.config import TrackerConfig

    return TrackerConfig.from_toml(path) if path else TrackerConfig()


class DepthFed:
    """A depth tracker behind the monocular tracker's `process(image, t)`: each frame's depth
    map is read from the sequence by its time. The tracker's other attributes (its map,
    mapper, backlog) are the wrapped tracker's."""

    def __init__(self, tracker, sequence):
        self.tracker, self.sequence = tracker, sequence
        self.first_depth_frame: int | None = None  # index of the first frame with depth
        self._frames = 0

    def __getattr__(self, name: str):
        return getattr(self.tracker, name)

    def process(self, image, t: float):
        """The tracker's FrameResult for the frame at time t, with its depth map."""
        depth = self.sequence.depth_at(t)
        if depth is not None and self.first_depth_frame is None:
            self.first_depth_frame = self._frames
        self._frames += 1
        return self.tracker.process(image, t, depth)

    def close(self) -> None:
        """Stop the tracker's threads, if any."""
        self.tracker.close()


def build_tracker(method: str, sequence, config, threaded: bool, stepped_mapping: bool):
    """A tracker for the sequence with `process(image, t)` and `close()`."""
    if method == "rgbd-sift":
        if threaded or stepped_mapping:
            raise InputError("--method rgbd-sift has no mapping thread (no --threaded, "
                             "--paced or --mapping-period)")
        from vo.rgbd_odometry import RgbdOdometry

        return DepthFed(RgbdOdometry(sequence.camera, config), sequence)
    from vo.tracker import Tracker

    tracker = Tracker(sequence.camera, config, threaded=threaded,
                      stepped_mapping=stepped_mapping)
    return DepthFed(tracker, sequence) if method == "sdvl-depth" else tracker
