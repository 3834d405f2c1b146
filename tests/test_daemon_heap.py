"""Freed memory goes back to the system (daemon/heap.py): holes left between blocks still in
use stay resident until the heap is trimmed."""

from __future__ import annotations

import subprocess
import sys

import pytest
from daemon_helpers import RunningService, service_config, wait_for

from daemon.heap import HeapTrim, malloc_trim
from sim.autopilot import SimAutopilot, SimOptions

HOLES = """
import os
from daemon.heap import HeapTrim

def rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

blocks = [bytearray(b"x" * 65536) for _ in range(2000)]  # 125 MB under the mmap threshold
del blocks[::2]  # every other one freed: holes between live blocks, the top cannot shrink
before = rss_mb()
HeapTrim().trim_now()
print(before, rss_mb())
"""


def test_a_trim_is_due_every_interval_and_not_more_often():
    heap = HeapTrim(interval_s=10.0, trim=lambda pad: 1)
    assert [heap.due(now) for now in (0.0, 0.05, 9.9, 10.0, 15.0, 20.1)] == [
        True, False, False, True, False, True]
    heap.trim_now()
    assert heap.trims == 1


@pytest.mark.skipif(malloc_trim() is None, reason="the C library has no malloc_trim (not glibc)")
def test_freed_holes_leave_the_resident_memory_when_trimmed():
    done = subprocess.run([sys.executable, "-c", HOLES], capture_output=True, text=True,
                          timeout=60, check=True)
    before, after = map(float, done.stdout.split())
    assert before - after > 40.0, (before, after)  # ~62 MB of holes


@pytest.mark.skipif(malloc_trim() is None, reason="the C library has no malloc_trim (not glibc)")
def test_the_running_service_trims_its_heap():
    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url))
        try:
            assert wait_for(lambda: run.service.heap.trims >= 1, 5.0)
        finally:
            assert run.stop() == 0
