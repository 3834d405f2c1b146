"""The replay's progress bar on stderr (tqdm)."""

from __future__ import annotations

import sys
from collections.abc import Iterable

from tqdm import tqdm

NON_TTY_INTERVAL_S = 10.0  # a log file gets a line this often, not a redrawn bar


def progress_bar(description: str, total: int | None, iterable: Iterable | None = None,
                 enabled: bool = True, unit: str = "frame") -> tqdm:
    """A tqdm bar on stderr for the project's commands (over `iterable` when given); a line
    every NON_TTY_INTERVAL_S when stderr is not a terminal."""
    return tqdm(iterable, total=total, desc=description, unit=unit, file=sys.stderr,
                disable=not enabled,
                mininterval=0.25 if sys.stderr.isatty() else NON_TTY_INTERVAL_S,
                dynamic_ncols=True)


class Progress:
    """The replay's bar: frames offered, with processed and tracked beside it."""

    def __init__(self, total: int, enabled: bool):
        self.total = max(total, 1)
        self.bar = progress_bar("replay", self.total, enabled=enabled)

    def __len__(self) -> int:
        return self.total

    def rendered(self, done: int) -> None:
        """Frames rendered before the replay (a line per 10 %)."""
        if done == self.total or done % max(self.total // 10, 1) == 0:
            self.note(f"  rendered {done}/{self.total} frames")

    def note(self, text: str) -> None:
        """One line of its own, above the bar."""
        if not self.bar.disable:
            self.bar.write(text, file=sys.stderr)

    def update(self, offered: int, processed: int, tracked: int) -> None:
        self.bar.set_postfix(processed=processed, tracked=tracked, refresh=False)
        self.bar.update(offered - self.bar.n)

    def close(self) -> None:
        self.bar.close()
