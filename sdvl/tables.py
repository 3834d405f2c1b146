"""Settings tables: TOML files read into validated dataclasses, with errors naming the key.

Shared by the tracker's and the service's configs. Every number must be finite (TOML has `nan`
and `inf`); a field may carry its own range or choices beside it (`bounded`, `one_of`), checked
for every table and every programmatic copy (`check_fields`), or its range may be kept in a
table of limits beside the class (`interval`, `check_limits`).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import typing
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from sdvl.errors import InputError, read_text

TYPE_NAMES = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}


def read_toml(path: str | Path) -> dict:
    """The parsed TOML file; InputError when it is missing or not valid TOML."""
    try:
        return tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", path) from None


def suggest(name: str, choices: Iterable[str]) -> str:
    """'did you mean ...?' for a mistyped name, else the list of known names."""
    choices = list(choices)
    close = difflib.get_close_matches(name, choices, n=1)
    return f"did you mean '{close[0]}'?" if close else f"known keys: {', '.join(choices)}"


@dataclass(frozen=True)
class Bounds:
    """An allowed interval; an open end excludes its value, None leaves that side free."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    why: str = ""  # what the limit protects, said after the range

    def contains(self, value: float) -> bool:
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open
                                     else value <= self.high)

    def __str__(self) -> str:
        if self.high is None:
            return f"{'>' if self.low_open else '>='} {self.low:g}"
        if self.low is None:
            return f"{'<' if self.high_open else '<='} {self.high:g}"
        if not self.low_open and not self.high_open:
            return f"{self.low:g}..{self.high:g}"
        return (f"in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}"
                f"{')' if self.high_open else ']'}")


def interval(low: float | None = None, high: float | None = None, *,
             above: float | None = None, below: float | None = None, why: str = "") -> Bounds:
    """[low, high], or (above, ...), (..., below): the Bounds of one setting."""
    return Bounds(above if above is not None else low, below if below is not None else high,
                  above is not None, below is not None, why)


def bounded(default: float, low: float | None = None, high: float | None = None, *,
            above: float | None = None, below: float | None = None, why: str = ""):
    """A dataclass field whose value must lie in [low, high] (or (above, ...), (..., below))."""
    bounds = interval(low, high, above=above, below=below, why=why)
    return dataclasses.field(default=default, metadata={"bounds": bounds})


def one_of(default: str, choices: tuple[str, ...]):
    """A dataclass field whose value must be one of `choices`."""
    return dataclasses.field(default=default, metadata={"choices": choices})


def _check_metadata(key: str, value: object, metadata: typing.Mapping,
                    path: str | Path | None) -> None:
    bounds, choices = metadata.get("bounds"), metadata.get("choices")
    if bounds is not None and not bounds.contains(value):
        why = f": {bounds.why}" if bounds.why else ""
        raise InputError(f"{key} must be {bounds}{why}, got {value!r}", path)
    if choices is not None and value not in choices:
        raise InputError(f"{key} must be one of {', '.join(choices)}, got {value!r}", path)


def checked_value(key: str, value: object, tp: type, path: str | Path | None) -> object:
    """`value` as type `tp` (an integer is accepted as a number) or an InputError naming `key`;
    a number must be finite."""
    if tp is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, tp) or (tp is int and isinstance(value, bool)):
        raise InputError(f"{key} must be {TYPE_NAMES[tp]}, got {value!r}", path)
    if tp is float and not math.isfinite(value):
        raise InputError(f"{key} must be a finite number, got {value!r}", path)
    return value


def check_fields(instance: object, section: str, path: str | Path | None = None) -> None:
    """InputError naming the first field of a settings dataclass that is not finite or is
    outside the range or choices declared beside it."""
    hints = typing.get_type_hints(type(instance))
    for f in dataclasses.fields(instance):
        value = getattr(instance, f.name)
        if hints[f.name] in TYPE_NAMES:
            checked_value(f"{section}.{f.name}", value, hints[f.name], path)
        _check_metadata(f"{section}.{f.name}", value, f.metadata, path)


def check_limits(instance: object, section: str, limits: typing.Mapping[str, Bounds],
                 path: str | Path | None = None) -> None:
    """InputError naming the first field outside its interval in `limits` (field name ->
    Bounds): the ranges of a settings dataclass kept in a table beside it."""
    for name, bounds in limits.items():
        _check_metadata(f"{section}.{name}", getattr(instance, name), {"bounds": bounds}, path)


def dataclass_from_table(cls: type, table: object, section: str,
                         path: str | Path | None = None) -> object:
    """An instance of the dataclass `cls` from one TOML table: unknown keys and wrong types are
    InputErrors naming `section.key`."""
    if not isinstance(table, dict):
        raise InputError(f"[{section}] must be a table, e.g. a line '[{section}]' followed by keys",
                         path)
    hints = typing.get_type_hints(cls)
    values = {}
    for key, value in table.items():
        if key not in hints:
            raise InputError(f"unknown key '{section}.{key}': {suggest(key, hints)}", path)
        values[key] = checked_value(f"{section}.{key}", value, hints[key], path)
    instance = cls(**values)
    check_fields(instance, section, path)
    return instance
