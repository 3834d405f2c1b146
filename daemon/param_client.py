"""The MAVLink parameter protocol from the companion's side: read every parameter the autopilot
has, set one and read it back.

Follows the protocol as ArduPilot (GCS_Param.cpp) and PX4 (mavlink_parameters.cpp) serve it:
PARAM_REQUEST_LIST is answered by one PARAM_VALUE per parameter carrying its index and the
count, so the ones a lossy link dropped are asked for again by index with PARAM_REQUEST_READ;
PARAM_SET is answered by a PARAM_VALUE with the value the autopilot now holds. PX4 carries
INT32 values bytewise in the float field (autopilot_params.wire_value).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from daemon.autopilot_params import from_wire, wire_value

QUIET_S = 1.0  # no PARAM_VALUE for this long: ask again for what is missing
READ_BATCH = 20  # indices asked for at once after a quiet spell
SET_WAIT_S = 1.5
SET_TRIES = 3


@dataclass(frozen=True)
class Param:
    """A parameter as the autopilot reported it."""

    value: float
    param_type: int


class ParamClient:
    """Fed every message (`on_message`); `fetch_all` and `set` talk to the autopilot at
    `target()` = (system, component) through `codec`."""

    def __init__(self, codec: object, target: Callable[[], tuple[int, int]],
                 flavour: Callable[[], str]):
        self.codec = codec
        self.target = target
        self.flavour = flavour
        self.params: dict[str, Param] = {}
        self.count: int | None = None
        self._indices: set[int] = set()
        self._answers: dict[str, int] = {}
        self._news = asyncio.Event()

    def on_message(self, msg: object) -> None:
        """Keep each PARAM_VALUE."""
        if msg.get_type() != "PARAM_VALUE":
            return
        value = from_wire(self.flavour(), msg.param_value, msg.param_type)
        self.params[msg.param_id] = Param(value, msg.param_type)
        self._answers[msg.param_id] = self._answers.get(msg.param_id, 0) + 1
        if 0 <= msg.param_index < msg.param_count:
            self.count = msg.param_count
            self._indices.add(msg.param_index)
        self._news.set()

    def values(self) -> dict[str, float]:
        """Name -> value of everything read so far."""
        return {name: p.value for name, p in self.params.items()}

    @property
    def complete(self) -> bool:
        return self.count is not None and len(self._indices) >= self.count

    async def fetch_all(self, timeout_s: float) -> dict[str, float]:
        """Every parameter the autopilot has (as many as arrived within timeout_s)."""
        mav = self.codec.mav
        self.codec.send(mav.param_request_list_encode(*self.target()))
        deadline = time.monotonic() + timeout_s
        while not self.complete and time.monotonic() < deadline:
            self._news.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._news.wait(), QUIET_S)
                continue
            if self.count is None:
                self.codec.send(mav.param_request_list_encode(*self.target()))
                continue
            missing = [i for i in range(self.count) if i not in self._indices][:READ_BATCH]
            for index in missing:
                self.codec.send(mav.param_request_read_encode(*self.target(), b"", index))
        return self.values()

    async def set(self, name: str, value: float) -> float | None:
        """PARAM_SET `name` and wait for the autopilot's PARAM_VALUE; the value it now holds,
        None when it never answered."""
        param_type = self.params[name].param_type
        wire = wire_value(self.flavour(), value, param_type)
        answered = False
        for _ in range(SET_TRIES):
            before = self._answers.get(name, 0)
            self.codec.send(self.codec.mav.param_set_encode(*self.target(), name.encode(),
                                                            wire, param_type))
            deadline = time.monotonic() + SET_WAIT_S
            while self._answers.get(name, 0) == before and time.monotonic() < deadline:
                self._news.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._news.wait(), deadline - time.monotonic())
            answered = answered or self._answers.get(name, 0) > before
            if answered and math.isclose(self.params[name].value, value, rel_tol=1e-5,
                                         abs_tol=1e-6):
                break
        return self.params[name].value if answered else None
