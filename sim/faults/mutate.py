"""Mutations of autopilot MAVLink messages that still arrive with a valid CRC: what a corrupted
autopilot, a wrong parameter, a confused router or an attacker on the radio can send.

Every mutation works on a copy of a pymavlink message and returns the packet bytes, packed
with the sender's own system and component id (so the CRC and the CRC_EXTRA are right); the
receiver can only judge the values.
"""

from __future__ import annotations

import copy
import math
import struct

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

FLOAT32_MAX = 3.4028234e38
INT_RANGES = {"uint8_t": (0, 2**8 - 1), "int8_t": (-2**7, 2**7 - 1),
              "uint16_t": (0, 2**16 - 1), "int16_t": (-2**15, 2**15 - 1),
              "uint32_t": (0, 2**32 - 1), "int32_t": (-2**31, 2**31 - 1),
              "uint64_t": (0, 2**64 - 1), "int64_t": (-2**63, 2**63 - 1)}
TIME_FIELDS = ("time_boot_ms", "time_usec")


class Packer:
    """Packs messages as one MAVLink system and component (its own sequence numbers)."""

    def __init__(self, system: int = 1, component: int = 1):
        self.mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)

    def pack(self, msg: object) -> bytes:
        return bytes(msg.pack(self.mav))


def _float_value(value: float, rng: np.random.Generator) -> float:
    """A float a broken sender might put there: non-finite, extreme, zero, scaled or shifted
    (plausible but wrong), or anything."""
    kind = rng.integers(8)
    if kind == 0:
        return float(rng.choice([math.nan, math.inf, -math.inf]))
    if kind == 1:
        return float(rng.choice([FLOAT32_MAX, -FLOAT32_MAX, 1e12, -1e12]))
    if kind == 2:
        return 0.0
    if kind in (3, 4):
        return float(value * rng.uniform(-3.0, 3.0))
    if kind in (5, 6):
        return float(value + rng.normal(0.0, abs(value) + 1.0))
    return float(rng.uniform(-1e6, 1e6))


def _int_value(value: int, kind: str, rng: np.random.Generator) -> int:
    low, high = INT_RANGES.get(kind, (0, 255))
    choice = rng.integers(5)
    if choice == 0:
        return int(rng.choice([low, high, 0]))
    if choice in (1, 2):
        spread = max(10, abs(int(value)) // 2)
        return int(np.clip(int(value) + int(rng.integers(-spread, spread + 1)), low, high))
    if high >= 2**63:  # beyond numpy's int64 draws; the low half is wrong enough
        return int(rng.integers(0, 2**62))
    return int(rng.integers(low, high, endpoint=True))


def _field_kinds(msg: object) -> dict[str, str]:
    return dict(zip(msg.fieldnames, msg.fieldtypes, strict=True))


def mutate_fields(msg: object, rng: np.random.Generator, count: int | None = None) -> object:
    """A copy of `msg` with 1-3 (or `count`) of its fields changed."""
    names = list(_field_kinds(msg))
    chosen = rng.choice(names, size=min(count or int(rng.integers(1, 4)), len(names)),
                        replace=False)
    out = copy.copy(msg)
    for name in chosen:
        _change(out, str(name), rng)
    return out


def mutate_field(msg: object, name: str, rng: np.random.Generator) -> object:
    """A copy of `msg` with its field `name` changed."""
    out = copy.copy(msg)
    _change(out, name, rng)
    return out


def _change(msg: object, name: str, rng: np.random.Generator) -> None:
    """Change one field of `msg` in place (one element of an array field)."""
    value, kind = getattr(msg, name), _field_kinds(msg)[name]
    if isinstance(value, list | tuple):
        value = list(value)
        k = int(rng.integers(len(value)))
        value[k] = (_float_value(value[k], rng) if kind in ("float", "double")
                    else _int_value(value[k], kind, rng))
    elif kind in ("float", "double"):
        value = _float_value(value, rng)
    elif kind == "char":
        value = bytes(rng.integers(32, 127, size=int(rng.integers(0, 20)), dtype=np.uint8))
    else:
        value = _int_value(value, kind, rng)
    setattr(msg, name, value)


def shift_time(msg: object, seconds: float) -> object:
    """A copy of `msg` whose boot stamp is `seconds` later (earlier when negative)."""
    out = copy.copy(msg)
    for name, scale in (("time_boot_ms", 1e3), ("time_usec", 1e6)):
        if hasattr(out, name):
            setattr(out, name, max(0, int(getattr(out, name) + seconds * scale)))
    return out


def pack_or_none(packer: Packer, msg: object) -> bytes | None:
    """The packet, or None when a value cannot be carried by the field (pymavlink refuses)."""
    try:
        return packer.pack(msg)
    except (struct.error, OverflowError, ValueError, TypeError):
        return None
