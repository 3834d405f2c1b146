"""Rendered frames of synthetic flights kept between runs, so that a second real-time replay of
the same flight starts after the tracker's warm-up instead of after rendering every frame again.

A flight's frames live in `<root>/<key>/`, where the key hashes everything the images depend on:
the preset's name and seed, the camera, the frame times, the first frame's pixels (textures,
scene) and the source of the renderer (`sim/synth`). Frames are rendered into a staging folder
beside it and renamed into place when complete, so a reader never sees a half-written flight and
two processes rendering the same flight both end with one complete copy. The newest
`KEEP_FLIGHTS` flights stay; older ones are deleted once nobody has used them for a while.

The root is the `frames` folder of sim.disk_cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from sim import disk_cache

KEEP_FLIGHTS = 3  # a few hundred MB: the default 25 s 640x480 flight is ~125 MB of PNG
IN_USE_S = 3600.0  # a flight or staging folder touched this recently may be in use elsewhere
STAGING_PREFIX = "staging-"


def cache_root() -> Path:
    """Where rendered flights are kept."""
    return disk_cache.cache_root("frames")


def flight_key(sequence: object, frames: int, first: np.ndarray) -> str:
    """The cache key of the first `frames` frames of `sequence`, whose frame 0 is `first`."""
    extras = getattr(sequence, "extras", {})
    camera = sequence.camera
    digest = hashlib.sha256(disk_cache.source_digest("synth"))
    digest.update(repr((sequence.name, extras.get("preset"), extras.get("seed"), frames,
                        camera.width, camera.height, camera.fx, camera.fy, camera.cx,
                        camera.cy)).encode())
    digest.update(np.ascontiguousarray(sequence.timestamps[:frames], np.float64).tobytes())
    digest.update(np.ascontiguousarray(first).tobytes())
    return f"{sequence.name}-{digest.hexdigest()[:24]}"


def lookup(key: str) -> Path | None:
    """The folder of a complete cached flight, marked as just used; None when not cached."""
    folder = cache_root() / key
    if not folder.is_dir():
        return None
    with contextlib.suppress(OSError):  # a read-only cache still serves its frames
        os.utime(folder)
    return folder


def staging() -> Path | None:
    """A new folder to render a flight into, or None (one warning) when the cache is not
    writable: the caller renders into a temporary folder, as without a cache."""
    root = cache_root()
    try:
        root.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=root))
    except OSError as exc:
        disk_cache.warn_unwritable(root, exc)
        return None


def publish(folder: Path, key: str) -> Path:
    """Move a completely rendered staging folder into place; the cached folder to read from
    (another process's copy when it finished first)."""
    target = cache_root() / key
    try:
        folder.rename(target)
    except OSError:  # already there (another process rendered it too)
        shutil.rmtree(folder, ignore_errors=True)
        if not target.is_dir():
            raise
    _evict()
    return target


def _evict() -> None:
    """Delete all but the newest KEEP_FLIGHTS flights, and stale staging folders, except what
    was used within IN_USE_S."""
    used = {path: _mtime(path) for path in cache_root().iterdir()}
    entries = sorted(used, key=used.get, reverse=True)
    flights = [p for p in entries if not p.name.startswith(STAGING_PREFIX)]
    stale = [p for p in entries if p.name.startswith(STAGING_PREFIX)] + flights[KEEP_FLIGHTS:]
    for path in stale:
        if time.time() - used[path] > IN_USE_S:
            shutil.rmtree(path, ignore_errors=True)


def _mtime(path: Path) -> float:
    """When `path` was last used; the epoch when another process just deleted it."""
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
