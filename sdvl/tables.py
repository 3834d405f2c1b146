"""Settings tables: TOML files read into validated dataclasses, with errors naming the key.

Shared by the tracker's and the service's configs.
"""

from __future__ import annotations

import difflib
import tomllib
import typing
from collections.abc import Iterable
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


def checked_value(key: str, value: object, tp: type, path: str | Path | None) -> object:
    """`value` as type `tp` (an integer is accepted as a number) or an InputError naming `key`."""
    if tp is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, tp) or (tp is int and isinstance(value, bool)):
        raise InputError(f"{key} must be {TYPE_NAMES[tp]}, got {value!r}", path)
    return value


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
    return cls(**values)
