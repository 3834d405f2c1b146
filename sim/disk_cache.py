"""What the simulator computes the same way every time (procedural textures, rendered flights),
kept on disk between runs so that a second run starts in seconds.

The folder is `$SDVL_CACHE_DIR`, else `$XDG_CACHE_HOME/sdvl-companion`, else
`~/.cache/sdvl-companion`; each kind of entry has its own subfolder. Keys hash the source that
computed an entry, so changed code never reads an old one. Entries are written under a temporary
name and renamed into place (two processes computing the same one both end with one whole copy);
an entry that cannot be written or read is computed again, with one warning.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

log = logging.getLogger("sdvl.cache")


def cache_root(kind: str) -> Path:
    """The folder for entries of one kind ('frames', 'textures')."""
    if os.environ.get("SDVL_CACHE_DIR"):
        return Path(os.environ["SDVL_CACHE_DIR"]) / kind
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "sdvl-companion" / kind


@functools.cache
def source_digest(package: str) -> bytes:
    """A digest of the Python source of `package` (a folder of sim/, e.g. 'synth')."""
    digest = hashlib.sha256()
    for path in sorted((Path(__file__).resolve().parent / package).glob("*.py")):
        digest.update(path.read_bytes())
    return digest.digest()


_WARNED: set[Path] = set()


def warn_unwritable(root: Path, error: OSError) -> None:
    """One warning per folder that cannot be written."""
    if root not in _WARNED:
        _WARNED.add(root)
        log.warning("%s is not writable (%s): computed again on every run; set SDVL_CACHE_DIR "
                    "to a writable folder", root, error.strerror or error)


def cached_array(kind: str, key: str, compute: Callable[[], np.ndarray]) -> np.ndarray:
    """The array stored under `key`, else `compute()`'s result, stored for the next run."""
    root = cache_root(kind)
    path = root / f"{key}.npy"
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        pass  # not there yet, or unreadable: computed again
    array = compute()
    temporary = None
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=root, suffix=".tmp", delete=False) as f:
            temporary = Path(f.name)
            np.save(f, array, allow_pickle=False)
        os.replace(temporary, path)
    except OSError as exc:
        if temporary is not None:
            temporary.unlink(missing_ok=True)
        warn_unwritable(root, exc)
    return array
