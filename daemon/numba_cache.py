"""Compiled kernels cached on disk when the disk allows it, compiled in memory when not.

How numba (0.6x, numba/core/caching.py and dispatcher.py) treats its cache: when a module with
`@njit(cache=True)` kernels is imported, each kernel gets a cache directory, NUMBA_CACHE_DIR if
set, else __pycache__ beside the source, else the user's cache directory, the first in which a
temporary file can be created; when none can, the import raises RuntimeError ("cannot cache
function ...: no locator available"). A directory that passes that test but is full makes the
kernel's first call raise OSError (ENOSPC) from `Cache.save_overload`, after the kernel was
compiled, so the tracking thread dies on a full disk.

`prepare()` runs before the kernels are imported. It writes a probe file into the directory
numba will use; if that fails, one warning, and this run compiles every kernel in memory
(`Dispatcher.enable_caching` leaves numba's NullCache in place): a slower start, nothing else.
Saving or loading one kernel's cache that fails later (the disk fills up, a corrupt file) is a
warning, once, and that kernel runs from memory.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import os
import tempfile
from pathlib import Path

log = logging.getLogger("sdvl.numba")
PROBE_BYTES = 1 << 20  # a few kernels' worth; the whole tracker's cache is tens of MB
KERNEL_PACKAGE = "vo"


def cache_dir() -> Path:
    """The directory numba caches the tracker's kernels in: NUMBA_CACHE_DIR, else vo's
    __pycache__."""
    from numba.core import config

    if config.CACHE_DIR:
        return Path(config.CACHE_DIR)
    return Path(importlib.util.find_spec(KERNEL_PACKAGE).origin).parent / "__pycache__"


def writable(path: Path, size: int = PROBE_BYTES) -> OSError | None:
    """None when `size` bytes can be written (and synced) in `path`, else the error."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path) as probe:
            probe.write(b"\0" * size)
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        return exc
    return None


def prepare() -> bool:
    """Before the kernels are imported: cache on disk if the directory takes a probe file,
    else compile in memory; later save/load failures become warnings. True: caching on."""
    _guard_cache_files()
    path = cache_dir()
    error = writable(path)
    if error is None:
        return True
    log.warning("numba cache %s is not usable (%s): compiling the kernels in memory this run "
                "(a slower start); free space there or set NUMBA_CACHE_DIR to a writable "
                "directory", path, error.strerror or error)
    from numba.core import dispatcher

    dispatcher.Dispatcher.enable_caching = _no_cache
    return False


def _no_cache(self: object) -> None:
    """Dispatcher.enable_caching that keeps the NullCache a dispatcher starts with."""


@functools.cache
def _guard_cache_files() -> None:
    """A kernel whose cache file cannot be written or read runs from memory (one warning)."""
    from numba.core import caching

    save, load = caching.Cache.save_overload, caching.Cache.load_overload

    def save_overload(self: caching.Cache, sig: object, data: object) -> None:
        try:
            save(self, sig, data)
        except OSError as exc:
            self.disable()
            _warn_once("save", f"numba cache: cannot save a compiled kernel ({exc}); kernels "
                       "not cached yet are compiled in memory (warned once)")

    def load_overload(self: caching.Cache, sig: object, target_context: object) -> object:
        try:
            return load(self, sig, target_context)
        except Exception as exc:  # a corrupt or unreadable cache file: compile instead
            _warn_once("load", f"numba cache: cannot load a compiled kernel ({exc}); compiling "
                       "it (warned once)")
            return None

    caching.Cache.save_overload = save_overload
    caching.Cache.load_overload = load_overload


def _warn_once(kind: str, text: str) -> None:
    if kind not in _WARNED:
        _WARNED.add(kind)
        log.warning("%s", text)


_WARNED: set[str] = set()
