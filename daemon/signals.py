"""Signals from the first moment of `sdvl run`, before the slow imports and the service loop.

SIGTERM and SIGINT while the service is still starting raise `Stopped`, which `sdvl run` turns
into a clean exit (code 0); once the asyncio loop runs, `hand_over` gives them to the service
(a clean stop) and SIGHUP to its reload. A SIGHUP while starting is logged and ignored (the
configuration is being read anyway); after the loop, both only set a flag, so nothing kills the
process by a signal while it finishes.
"""

from __future__ import annotations

import asyncio
import logging
import signal
from collections.abc import Callable

log = logging.getLogger("sdvl.signals")
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class Stopped(BaseException):  # like KeyboardInterrupt: not an error
    """SIGTERM or SIGINT arrived before the service loop ran."""


class EarlySignals:
    """Install with `install()` as the first thing `sdvl run` does."""

    def __init__(self) -> None:
        self.stop_requested = False
        self.starting = True

    def install(self) -> None:
        """SIGHUP first: once SIGTERM is caught, a reload can no longer kill the process."""
        signal.signal(signal.SIGHUP, self._hangup)
        for sig in STOP_SIGNALS:
            signal.signal(sig, self._stop)

    def _stop(self, signum: int, frame: object) -> None:
        self.stop_requested = True
        if self.starting:
            raise Stopped(signal.Signals(signum).name)

    def _hangup(self, signum: int, frame: object) -> None:
        log.warning("SIGHUP %s: ignored", "while starting (the configuration is being read "
                    "now)" if self.starting else "while stopping")

    def hand_over(self, loop: asyncio.AbstractEventLoop, stop: Callable[[], None],
                  reload: Callable[[], None]) -> None:
        """From now on the service's loop handles SIGTERM/SIGINT (stop) and SIGHUP (reload);
        a stop asked for before this is passed on at once."""
        for sig in STOP_SIGNALS:
            loop.add_signal_handler(sig, stop)
        loop.add_signal_handler(signal.SIGHUP, reload)
        if self.stop_requested:
            stop()

    def finish(self) -> None:
        """After the loop: signals only set the flag (the loop's handlers are gone)."""
        self.starting = False
        self.install()
