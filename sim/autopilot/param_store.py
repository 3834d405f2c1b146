"""The autopilot's parameter storage: stored values (what PARAM_VALUE reports, kept across a
reboot), RAM-only changes (lost at a reboot), and the values the running firmware took at boot
for parameters that need a reboot.

Setting from MAVLink follows each firmware: ArduPilot casts PARAM_SET's float to the
parameter's type (AP_Param::set_float, truncating after a 0.01 nudge, clamped to the type's
range); PX4 copies PARAM_SET's four bytes into the parameter whatever type the sender declared
(mavlink_parameters.cpp), so an INT32 sent as a REAL32 3.0 is stored as 1077936128. On the wire
ArduPilot sends every value as a float, PX4 an INT32's bytes (the "bytewise" encoding).
"""

from __future__ import annotations

import math
import struct

from sim.autopilot.params import INT8, INT16, INT32, REAL32, ParamSpec

TYPE_RANGE = {INT8: (-128, 127), INT16: (-32768, 32767), INT32: (-2**31, 2**31 - 1)}


def px4_wire(value: float, kind: int) -> float:
    """The float PX4 puts in PARAM_VALUE: an INT32's bytes read as a float."""
    if kind == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def px4_from_wire(raw: float, kind: int) -> float:
    """What PX4 stores from PARAM_SET's float field for a parameter of type `kind`."""
    if kind == INT32:
        return float(struct.unpack("<i", struct.pack("<f", raw))[0])
    return float(raw)


def ardupilot_cast(value: float, kind: int) -> float:
    """AP_Param::set_float: integer types take the float nudged by 0.01 towards its sign and
    truncated, clamped to the type."""
    if kind == REAL32:
        return float(value)
    low, high = TYPE_RANGE[kind]
    nudged = value + math.copysign(0.01, value)
    return float(min(max(int(nudged), low), high))


class ParamStore:
    """Parameters of one autopilot. `boot()` takes the values a reboot-required parameter runs
    with; `get` returns what the running firmware uses."""

    def __init__(self, specs: dict[str, ParamSpec], stored: dict[str, float]):
        self.specs = dict(specs)
        self.saved = {name: float(spec.default) for name, spec in specs.items()}
        self.saved.update({k: float(v) for k, v in stored.items() if k in self.specs})
        self.values = dict(self.saved)
        self._active = dict(self.values)

    def boot(self, specs: dict[str, ParamSpec] | None = None) -> None:
        """A reboot: RAM-only values are lost, reboot-required values take effect; `specs`
        replaces the table (parameters that exist depend on others, e.g. MAVn_*)."""
        if specs is not None:
            self.specs = dict(specs)
            self.saved = {k: self.saved.get(k, float(s.default)) for k, s in specs.items()}
        self.values = dict(self.saved)
        self._active = dict(self.values)

    def __contains__(self, name: str) -> bool:
        return name in self.specs

    def __iter__(self):
        return iter(self.specs)

    def names(self) -> list[str]:
        return list(self.specs)

    def get(self, name: str, default: float = 0.0) -> float:
        """The value the running firmware uses (the boot value when it needs a reboot)."""
        if name not in self.specs:
            return default
        return self._active[name] if self.specs[name].reboot else self.values[name]

    def stored(self, name: str) -> float:
        return self.values[name]

    def set(self, name: str, value: float, persist: bool = True) -> None:
        """Change a value (already cast by the caller's firmware rule); `persist=False` keeps
        it in RAM only, as ArduPilot Copter's REQUEST_DATA_STREAM does."""
        self.values[name] = float(value)
        if persist:
            self.saved[name] = float(value)

