"""The simulated autopilot's end of a link: UDP, TCP server or a pseudo-terminal serial pair.

Each port is polled by the simulator's thread: `fileno()` for select, `read()` for what came in,
`write()` to send (silently dropped when no companion is attached yet), `url` for the companion.
"""

from __future__ import annotations

import contextlib
import os
import socket
import tty

BAUD = 921600
RECEIVE_BUFFER = 4 * 1024 * 1024


class UdpPort:
    """Listens on 127.0.0.1; replies go to the last address heard from (like ArduPilot's
    udpin)."""

    def __init__(self, port: int = 0):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # room for seconds of vision if a busy test machine starves this thread
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.peer: tuple | None = None
        self.url = f"udpout:127.0.0.1:{self.sock.getsockname()[1]}"

    def fileno(self) -> int:
        return self.sock.fileno()

    def read(self) -> bytes:
        """Every datagram waiting (MAVLink frames may be concatenated)."""
        chunks = []
        while True:
            try:
                data, self.peer = self.sock.recvfrom(65536)
            except (BlockingIOError, OSError):
                return b"".join(chunks)
            chunks.append(data)

    def write(self, data: bytes) -> None:
        if self.peer is not None:
            with contextlib.suppress(OSError):
                self.sock.sendto(data, self.peer)

    def close(self) -> None:
        self.sock.close()


class TcpPort:
    """A TCP server for one client at a time (like SITL's tcp:5760)."""

    def __init__(self, port: int = 0):
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind(("127.0.0.1", port))
        self.server.listen(1)
        self.server.setblocking(False)
        self.client: socket.socket | None = None
        self.url = f"tcp:127.0.0.1:{self.server.getsockname()[1]}"

    def fileno(self) -> int:
        return (self.client or self.server).fileno()

    def read(self) -> bytes:
        if self.client is None:
            with contextlib.suppress(BlockingIOError):
                self.client, _ = self.server.accept()
                self.client.setblocking(False)
            return b""
        try:
            data = self.client.recv(65536)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self.drop_client()
        return data

    def drop_client(self) -> None:
        """Close the connection (the companion must reconnect)."""
        if self.client is not None:
            self.client.close()
            self.client = None

    def write(self, data: bytes) -> None:
        if self.client is not None:
            try:
                self.client.sendall(data)
            except OSError:
                self.drop_client()

    def close(self) -> None:
        self.drop_client()
        self.server.close()


class PtyPort:
    """A pseudo-terminal pair: the simulator holds the master, the companion opens the slave
    path as a serial port. The slave is kept open here and set raw, so bytes are never echoed
    or line-edited whether or not the companion has it open."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.device = os.ttyname(self.slave)
        self.url = f"serial:{self.device}:{BAUD}"

    def fileno(self) -> int:
        return self.master

    def read(self) -> bytes:
        try:
            return os.read(self.master, 65536)
        except (BlockingIOError, OSError):
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                return  # the companion is not reading: drop, like a full UART buffer
            view = view[n:]

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)


def open_port(kind: str):
    """'udp', 'tcp' or 'pty'."""
    return {"udp": UdpPort, "tcp": TcpPort, "pty": PtyPort}[kind]()
