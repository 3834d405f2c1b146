"""Turn a stream of images into usable board views, saying why each bad image was skipped.

Image lists: every image is judged and each bad one is named with its reason. Video and live
device: a frame is kept only when the board is sharp, whole and has moved (`MotionGate`); the
others are only counted, since most frames of a stream are near-duplicates.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from calib.board import BoardDetector
from calib.calibration import View
from calib.view_quality import missing_board_reason, view_problem
from calib.view_selection import MotionGate


@dataclass
class CollectedViews:
    """Usable views, named skipped images with reasons, stream counts and the image size."""

    views: list[View] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)
    size: tuple[int, int] | None = None
    images: dict[str, np.ndarray] = field(default_factory=dict)


def _problem(grey: np.ndarray | str, detector: BoardDetector, size: tuple[int, int] | None,
             max_blur_px: float):
    """(detection, None) for a usable view, (None, reason) otherwise."""
    if isinstance(grey, str):
        return None, f"cannot read image: {grey}"
    if size is not None and (grey.shape[1], grey.shape[0]) != size:
        return None, (f"image is {grey.shape[1]}x{grey.shape[0]}, the first one was "
                      f"{size[0]}x{size[1]}")
    detection = detector.detect(grey)
    if detection is None:
        return None, missing_board_reason(grey, detector.spec) if detector.thorough else \
            "no board found"
    reason = view_problem(grey, detection, max_blur_px)
    return (None, reason) if reason else (detection, None)


def collect_views(frames: Iterable[tuple[str, np.ndarray | str]], detector: BoardDetector,
                  max_blur_px: float, gate: MotionGate | None = None,
                  stop_after: int | None = None, keep_images: bool = False,
                  log: Callable[[str], None] | None = None) -> CollectedViews:
    """Detect and check the board in each frame; with a `gate`, keep only frames where it moved.

    A frame given as a string instead of an image is one that could not be read (the reason).

    Stops after `stop_after` kept views or on Ctrl-C (live mode), keeping what it has.
    """
    out = CollectedViews()
    try:
        for name, grey in frames:
            out.counts["frames"] += 1
            detection, reason = _problem(grey, detector, out.size, max_blur_px)
            if out.size is None and not isinstance(grey, str):
                out.size = (grey.shape[1], grey.shape[0])
            if reason is not None:
                out.counts[reason.split(" (")[0]] += 1
                if gate is None:
                    out.skipped.append((name, reason))
                continue
            if gate is not None and not gate.accept(detection):
                out.counts["board did not move"] += 1
                continue
            out.views.append(View(name, detection))
            if keep_images:
                out.images[name] = grey
            if log is not None and gate is not None:
                log(f"kept view {len(out.views)} ({name})")
            if stop_after is not None and len(out.views) >= stop_after:
                break
    except KeyboardInterrupt:
        if log is not None:
            log(f"stopped by Ctrl-C with {len(out.views)} views")
    return out


def thin_views(views: list[View], max_views: int) -> list[View]:
    """At most `max_views` views, evenly spread over the sequence."""
    if len(views) <= max_views:
        return views
    keep = np.unique(np.linspace(0, len(views) - 1, max_views).round().astype(int))
    return [views[i] for i in keep]
