"""The one error type for bad user input, shared by every package and the command line."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad user input (file, config, argument): reported as one line, exit code 2, no traceback."""

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        self.message = message
        self.path = None if path is None else str(path)
        self.line = line
        super().__init__(str(self))

    def __str__(self) -> str:
        where = ""
        if self.path is not None:
            where = self.path if self.line is None else f"{self.path}:{self.line}"
            where += ": "
        return where + self.message


def read_text(path: str | Path) -> str:
    """The text of a user-named file; InputError saying why when it cannot be read."""
    try:
        return Path(path).read_text()
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text: {exc}", path) from None
