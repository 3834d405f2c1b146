"""The virtual-clock loop's dropped frames (sim/flight/frame_drops.py): the share asked for, in
runs, the same for a seed."""

from __future__ import annotations

import numpy as np
import pytest

from sim.flight.frame_drops import MEAN_RUN, FrameDrops


def _pattern(share: float, seed: int, n: int = 30000) -> np.ndarray:
    drops = FrameDrops(share, seed)
    return np.array([drops.drop() for _ in range(n)])


@pytest.mark.parametrize("share", [0.1, 0.2, 0.4])
def test_the_share_is_dropped_in_runs(share):
    dropped = _pattern(share, seed=3)
    assert dropped.mean() == pytest.approx(share, abs=0.015)
    starts = np.flatnonzero(np.diff(dropped.astype(int)) == 1)
    assert dropped.sum() / len(starts) == pytest.approx(MEAN_RUN, rel=0.1)


def test_seeded_and_none_by_default():
    np.testing.assert_array_equal(_pattern(0.2, 5, 500), _pattern(0.2, 5, 500))
    assert not np.array_equal(_pattern(0.2, 5, 500), _pattern(0.2, 6, 500))
    assert not _pattern(0.0, 5, 500).any()
    with pytest.raises(ValueError):
        FrameDrops(1.0, 0)
