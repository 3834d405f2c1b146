"""Reading whitespace- or comma-separated numeric text files with errors that name file and line."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sdvl.errors import InputError, read_text


def read_lines(path: str | Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) for each non-empty, non-comment line of a text file."""
    text = read_text(path)
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        yield number, line.replace(",", " ").split()


def parse_floats(fields: list[str], path: str | Path, line: int, expected: str) -> list[float]:
    """The fields as floats; InputError naming the line and what was expected otherwise."""
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise InputError(f"expected {expected}, got '{' '.join(fields)}'", path, line) from None
    if not all(np.isfinite(values)):
        raise InputError(f"expected {expected}, got a non-finite value", path, line)
    return values


def read_numeric_table(path: str | Path, columns: int, expected: str) -> np.ndarray:
    """An (N, columns) float array from a numeric text file, every row `columns` values."""
    rows = []
    for line, fields in read_lines(path):
        if len(fields) != columns:
            raise InputError(f"expected {expected} ({columns} values), got {len(fields)}",
                             path, line)
        rows.append(parse_floats(fields, path, line, expected))
    return np.array(rows, dtype=np.float64).reshape(-1, columns)


def check_increasing(times: np.ndarray, path: str | Path, what: str = "timestamps") -> None:
    """InputError unless `times` strictly increase."""
    bad = np.nonzero(np.diff(times) <= 0)[0]
    if bad.size:
        raise InputError(f"{what} must strictly increase (entry {bad[0] + 2} is not after "
                         f"entry {bad[0] + 1})", path)
