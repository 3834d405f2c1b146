"""The latency an autopilot must be told (VISO_DELAY_MS, EKF2_EV_DELAY), from what is measured.

Capture-to-send is measured by running the service itself for a few seconds: this machine's
camera (or test pattern) and tracker, the pass-through estimator, sending to a local UDP sink.
Not in the figure: the fusion's own update (it needs an autopilot's sensors; `sdvl
bench-latency` reports it as estimator_ms) and the camera's delay from exposure to the stamp the
capture takes (the V4L2 buffer stamp, or the moment the frame was read). The link's share is
half the TIMESYNC round trip measured to the autopilot. How each autopilot uses our capture
stamps decides what the delay must be:
- ArduPilot (AP_RTC/JitterCorrection.cpp) maps a stamp to its clock by the smallest
  arrival-minus-stamp offset of each 100 messages, so a message counts as taken at its capture
  time plus the fastest message's latency; the delay parameter must hold that fastest
  capture-to-arrival time.
- PX4 (src/lib/timesync/Timesync.cpp) maps stamps through TIMESYNC, whose samples it drops when
  the round trip is over 10 ms: with a faster link the stamps are right and the delay is 0;
  otherwise it stamps on arrival and the delay is the typical capture-to-arrival time.
"""

from __future__ import annotations

import asyncio
import socket
import statistics
import time

from daemon.config import Config, replace
from daemon.run_command import camera_model, open_source, tracker_factory
from daemon.service import Service

JITTER_WINDOW = 100  # ArduPilot's JitterCorrection convergence loops
PX4_MAX_RTT_S = 0.010  # PX4 Timesync MAX_RTT_SAMPLE
WARMUP_SENDS = 30  # the first estimates include compilation and the map's start
FIRST_FRAME_S = 90.0  # the first run of the tracker compiles its kernels


def ardupilot_delay_ms(capture_to_send_s: list[float], rtt_s: list[float],
                       source: str) -> tuple[float, str]:
    """VISO_DELAY_MS: the fastest capture-to-arrival, as ArduPilot's jitter correction sees it
    (the median over windows of JITTER_WINDOW messages of each window's fastest)."""
    windows = [capture_to_send_s[i:i + JITTER_WINDOW]
               for i in range(0, len(capture_to_send_s), JITTER_WINDOW)]
    fastest = statistics.median(min(w) for w in windows) * 1e3
    link = statistics.median(rtt_s) * 1e3 / 2 if rtt_s else 0.0
    how = f"half the TIMESYNC round trip {link:.1f} ms" if rtt_s else "no TIMESYNC answer: 0"
    return fastest + link, f"capture-to-send {fastest:.0f} ms ({source}) + {how}"


def px4_delay_ms(capture_to_send_s: list[float], rtt_s: list[float],
                 source: str) -> tuple[float, str]:
    """EKF2_EV_DELAY: 0 when PX4's TIMESYNC can map our stamps, else capture-to-arrival."""
    rtt = statistics.median(rtt_s) if rtt_s else None
    if rtt is not None and rtt < PX4_MAX_RTT_S:
        return 0.0, (f"TIMESYNC round trip {rtt * 1e3:.1f} ms: PX4 maps our capture stamps "
                     "to its clock")
    typical = statistics.median(capture_to_send_s) * 1e3
    link = rtt * 1e3 / 2 if rtt is not None else 0.0
    why = (f"TIMESYNC round trip {rtt * 1e3:.0f} ms is over PX4's 10 ms" if rtt is not None
           else "no TIMESYNC answer")
    return typical + link, (f"{why}, so it stamps our messages on arrival: capture-to-send "
                            f"{typical:.0f} ms ({source}) + {link:.1f} ms link")


def measure_capture_to_send(config: Config, seconds: float, source: object = None,
                            make_tracker: object = None) -> list[float]:
    """Capture-to-send latencies (s) of the service on this machine, after a warm-up; an empty
    list when no frame came. `source` and `make_tracker` default to the config's camera and
    the real tracker."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.bind(("127.0.0.1", 0))
        cfg = replace(config, mavlink={"link": f"udpout:127.0.0.1:{sink.getsockname()[1]}"},
                      fusion={"enabled": False})
        source = source or open_source(cfg.camera)
        make_tracker = make_tracker or tracker_factory(cfg, camera_model(cfg.camera, source))
        service = Service(cfg, source, make_tracker)
        asyncio.run(_run_for(service, seconds))
    return list(service.stats.send_latency_s)[WARMUP_SENDS:]


async def _run_for(service: Service, seconds: float) -> None:
    """Run the service until `seconds` after its first warm-up sends (or no frame came)."""
    task = asyncio.create_task(service.run())
    deadline = time.monotonic() + FIRST_FRAME_S
    while service.stats.sent < WARMUP_SENDS and time.monotonic() < deadline and not task.done():
        await asyncio.sleep(0.1)
    if service.stats.sent >= WARMUP_SENDS:
        await asyncio.sleep(seconds)
    service.stop()
    await task
