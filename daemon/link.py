"""Byte transports to the autopilot on asyncio: UDP (listen or send), TCP (connect or accept),
serial.

A Link delivers received bytes to a callback and writes bytes when it can. It opens itself in
the background and reopens after errors with back-off, so a missing device or a port in use is
logged once per attempt and retried, never fatal. The URL forms (pymavlink's) are in
daemon/link_url.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
from collections.abc import Callable

import serial

from daemon.link_url import LinkKind, LinkSpec, parse_link_url

log = logging.getLogger("sdvl.link")
MAX_BACKLOG = 64 * 1024  # bytes queued for a slow serial port or TCP peer


class Link:
    """Base: background (re)opening with back-off; subclasses implement _open/_close/write."""

    def __init__(self, spec: LinkSpec, on_bytes: Callable[[bytes], None],
                 retry_min_s: float = 0.2, retry_max_s: float = 5.0):
        self.spec = spec
        self.on_bytes = on_bytes
        self.retry = (retry_min_s, retry_max_s)
        self.connected = False
        self.last_error: str | None = None  # why the last attempt to open failed
        self.bytes_in = 0
        self.bytes_out = 0
        self._task: asyncio.Task | None = None
        self._broken = asyncio.Event()

    def start(self) -> None:
        """Begin opening in the background (call from the running loop)."""
        self._task = asyncio.get_running_loop().create_task(self._keep_open())

    async def _keep_open(self) -> None:
        delay = self.retry[0]
        while True:
            try:
                await self._open()
            except (OSError, serial.SerialException) as exc:
                self.last_error = str(exc)
                log.warning("link %s: cannot open (%s); retrying in %.1f s", self.spec, exc, delay)
                await asyncio.sleep(delay)
                delay = min(2 * delay, self.retry[1])
                continue
            log.info("link %s: open", self.spec)
            self.last_error = None
            self.connected, delay = True, self.retry[0]
            self._broken.clear()
            await self._broken.wait()
            self.connected = False
            self._close()
            log.warning("link %s: lost; reopening", self.spec)
            await asyncio.sleep(delay)

    def _received(self, data: bytes) -> None:
        self.bytes_in += len(data)
        self.on_bytes(data)

    def _mark_broken(self) -> None:
        self._broken.set()

    async def close(self) -> None:
        """Stop reopening and release the transport."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        self._close()
        self.connected = False

    async def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def write(self, data: bytes) -> bool:
        """Queue `data` for sending; False when there is nowhere to send it yet."""
        raise NotImplementedError


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, link: UdpLink):
        self.link = link

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        if self.link.spec.kind == LinkKind.UDP_IN:
            self.link.peer = addr
        self.link._received(data)

    def error_received(self, exc: Exception) -> None:
        log.debug("link %s: %s", self.link.spec, exc)  # ICMP unreachable: the peer is not up yet


class UdpLink(Link):
    """udpout (fixed peer) or udpin (reply to the last sender)."""

    peer: tuple | None = None
    _transport: asyncio.DatagramTransport | None = None

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        address = (self.spec.host, self.spec.port)
        if self.spec.kind == LinkKind.UDP_OUT:
            self.peer = address
            self._transport, _ = await loop.create_datagram_endpoint(
                lambda: _Datagrams(self), remote_addr=address)
        else:
            self._transport, _ = await loop.create_datagram_endpoint(
                lambda: _Datagrams(self), local_addr=address)

    def _close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def write(self, data: bytes) -> bool:
        if self._transport is None or self.peer is None:
            return False
        if self.spec.kind == LinkKind.UDP_OUT:
            self._transport.sendto(data)
        else:
            self._transport.sendto(data, self.peer)
        self.bytes_out += len(data)
        return True


class _Stream(asyncio.Protocol):
    """One TCP connection: bytes to the link; a lost client connection breaks a client link
    (it reconnects) and only forgets the client of a server link (it keeps listening)."""

    def __init__(self, link: TcpLink):
        self.link = link
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        self.link._connection_made(transport)

    def data_received(self, data: bytes) -> None:
        self.link._received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.link._connection_lost(self.transport)


class TcpLink(Link):
    """tcp: a TCP client that reconnects when the server goes away."""

    _transport: asyncio.Transport | None = None

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        await loop.create_connection(lambda: _Stream(self), self.spec.host, self.spec.port)

    def _connection_made(self, transport: asyncio.Transport) -> None:
        self._transport = transport

    def _connection_lost(self, transport: asyncio.Transport) -> None:
        self._mark_broken()

    def _close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def write(self, data: bytes) -> bool:
        if self._transport is None or self._transport.is_closing():
            return False
        if self._transport.get_write_buffer_size() > MAX_BACKLOG:
            return False  # the peer stopped reading: drop rather than grow without bound
        self._transport.write(data)
        self.bytes_out += len(data)
        return True


class TcpServerLink(TcpLink):
    """tcpin: listen and serve one TCP client at a time; a new client replaces the old one
    (as pymavlink's tcpin does)."""

    _server: asyncio.AbstractServer | None = None

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _Stream(self), self.spec.host,
                                                self.spec.port, reuse_address=True)

    def _connection_made(self, transport: asyncio.Transport) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.close()
        self._transport = transport
        log.info("link %s: client %s connected", self.spec,
                 transport.get_extra_info("peername"))

    def _connection_lost(self, transport: asyncio.Transport) -> None:
        if transport is self._transport:
            self._transport = None

    def _close(self) -> None:
        super()._close()
        if self._server is not None:
            self._server.close()
            self._server = None


class SerialLink(Link):
    """A serial port (or pseudo-terminal) read and written without blocking the loop."""

    _port: serial.Serial | None = None
    _backlog = b""

    async def _open(self) -> None:
        self._port = serial.Serial(self.spec.device, self.spec.baud, timeout=0, write_timeout=0,
                                   exclusive=True)
        loop = asyncio.get_running_loop()
        loop.add_reader(self._port.fileno(), self._readable)

    def _readable(self) -> None:
        try:
            data = os.read(self._port.fileno(), 4096)
        except OSError as exc:
            log.warning("link %s: read failed (%s)", self.spec, exc)
            data = b""
        if not data:  # hang-up or device removed
            self._stop_io()
            self._mark_broken()
            return
        self._received(data)

    def _stop_io(self) -> None:
        if self._port is not None and self._port.fd is not None:
            loop = asyncio.get_running_loop()
            loop.remove_reader(self._port.fd)
            loop.remove_writer(self._port.fd)

    def _close(self) -> None:
        if self._port is not None:
            with contextlib.suppress(Exception):
                self._stop_io()
            self._port.close()
            self._port = None
        self._backlog = b""

    def write(self, data: bytes) -> bool:
        if self._port is None or not self.connected:
            return False
        if len(self._backlog) + len(data) > MAX_BACKLOG:
            log.warning("link %s: output backlog full, dropping %d bytes", self.spec, len(data))
            return False
        had_backlog = bool(self._backlog)
        self._backlog += data
        self.bytes_out += len(data)
        if not had_backlog:
            self._flush()
        return True

    def _flush(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            n = os.write(self._port.fileno(), self._backlog)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            log.warning("link %s: write failed (%s)", self.spec, exc)
            self._stop_io()
            self._mark_broken()
            return
        self._backlog = self._backlog[n:]
        if self._backlog:
            loop.add_writer(self._port.fileno(), self._flush)
        else:
            loop.remove_writer(self._port.fileno())


def open_link(url: str, on_bytes: Callable[[bytes], None]) -> Link:
    """The Link for `url` (not yet started)."""
    spec = parse_link_url(url)
    cls = {LinkKind.UDP_OUT: UdpLink, LinkKind.UDP_IN: UdpLink, LinkKind.TCP: TcpLink,
           LinkKind.TCP_IN: TcpServerLink, LinkKind.SERIAL: SerialLink}[spec.kind]
    return cls(spec, on_bytes)
