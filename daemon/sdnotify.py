"""sd_notify: READY, WATCHDOG, STATUS and STOPPING datagrams to systemd's $NOTIFY_SOCKET.

Written here (a few lines) rather than depending on a package: the protocol is one datagram of
"KEY=value" lines to a unix socket, '@' meaning the abstract namespace.
"""

from __future__ import annotations

import logging
import os
import socket
import time

log = logging.getLogger("sdvl.systemd")


class Notifier:
    """Sends notifications when started by systemd with Type=notify; otherwise does nothing."""

    def __init__(self, environ: dict | None = None):
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        self.address = "\0" + address[1:] if address.startswith("@") else address
        watchdog_usec = int(env.get("WATCHDOG_USEC", "0") or 0)
        self.watchdog_interval_s = watchdog_usec / 2e6 if watchdog_usec > 0 else None
        self._sock: socket.socket | None = None
        self.stopping_sent = False
        if self.address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, *lines: str) -> bool:
        """Send 'KEY=value' lines as one datagram; False if not under systemd or it failed."""
        if self._sock is None:
            return False
        try:
            self._sock.sendto("\n".join(lines).encode(), self.address)
        except OSError as exc:
            log.warning("sd_notify failed: %s", exc)
            return False
        return True

    def stopping(self) -> None:
        """STOPPING=1, once, whichever way the process ends."""
        if not self.stopping_sent:
            self.stopping_sent = True
            self.notify("STOPPING=1")

    def reloading(self) -> None:
        """RELOADING=1 with the monotonic time systemd wants with it; READY=1 ends it."""
        self.notify("RELOADING=1", f"MONOTONIC_USEC={time.monotonic_ns() // 1000}")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
