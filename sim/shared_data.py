"""Where the read-only shared data lives: $SDVL_DATA, or ../shared/data beside the checkout."""

from __future__ import annotations

import os
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """$SDVL_DATA when set and not empty (an empty value, as a systemd `Environment=SDVL_DATA=`
    line leaves it, would otherwise mean the working directory), else ../shared/data."""
    data = os.environ.get("SDVL_DATA")
    return Path(data) if data else CHECKOUT.parent / "shared" / "data"
