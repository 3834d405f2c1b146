"""The service keeps going: autopilot link loss and reboot, new map segments, lost tracking,
stale poses."""

from __future__ import annotations

import time

import numpy as np
from daemon_helpers import FakeTracker, RunningService, service_config, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from sim.autopilot import SimAutopilot, configured_options

ORIGIN = {"enabled": True, "latitude_deg": 47.0, "longitude_deg": 8.0, "resend_interval_s": 0.2}


def test_link_loss_then_autopilot_reboot_recovered():
    """Loss: heartbeats stop, the service notices and, when they return, checks the origin.
    Reboot: the origin is gone; the service sets it again. Vision never stops for long."""
    with SimAutopilot(configured_options(heartbeat_hz=5, ekf_ready_after_s=0.3)) as sim:
        run = RunningService(service_config(sim.url, origin=ORIGIN))
        assert wait_for(lambda: sim.origin is not None, 5.0)
        watch = run.service.watch
        sim.lose_link(1.0)
        assert wait_for(lambda: not watch.alive, 3.0)  # heartbeat timeout 0.6 s
        assert wait_for(lambda: watch.alive, 3.0)
        assert watch.losses == 1
        t_back = time.monotonic() + 1.0
        sim.reboot(downtime_s=1.0)
        assert wait_for(lambda: sim.origin is None, 2.0)  # forgotten at boot
        assert wait_for(lambda: sim.origin is not None, 5.0)
        time.sleep(0.5)
        run.stop()
    assert watch.losses == 2
    accepted = [a for a in sim.origin_attempts if a[2]]
    assert len(accepted) == 2  # once per boot
    assert accepted[1][0] >= t_back
    texts = [r.msg.text for r in sim.messages("STATUSTEXT")]
    assert "VIO: autopilot reconnected" in texts
    arrivals = np.array([r.t for r in sim.messages("ODOMETRY")])
    after = arrivals[arrivals > t_back]
    assert len(after) >= 20  # the vision stream resumed with the link
    assert sim.bad_frames == 0


def test_quick_reboot_seen_from_boot_time():
    """A reboot shorter than the heartbeat timeout is caught by time_boot_ms going back."""
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, origin=ORIGIN,
                                            mavlink={"heartbeat_timeout_s": 2.0}))
        assert wait_for(lambda: sim.origin is not None, 5.0)
        time.sleep(1.2)  # boot time must be over a second to see it step back
        sim.reboot(downtime_s=0.2)
        assert wait_for(lambda: run.service.watch.reboots == 1, 3.0)
        assert wait_for(lambda: sim.origin is not None, 3.0)
        run.stop()
    assert run.service.watch.losses == 0
    assert len([a for a in sim.origin_attempts if a[2]]) == 2
    assert "VIO: autopilot rebooted" in [r.msg.text for r in sim.messages("STATUSTEXT")]


def lost_then_new_map(index: int) -> tuple[str, bool]:
    """Frames 0-29 good (first map), 30-39 lost, 40 on a new map."""
    if index < 30:
        return "good", index == 0
    if index < 40:
        return "lost", False
    return "good", index == 40


def test_new_map_segment_increments_reset_counter():
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, mavlink={"output": "both"}),
                             tracker=FakeTracker(lost_then_new_map))
        assert wait_for(lambda: len(sim.messages("ODOMETRY")) >= 50, 8.0)
        assert wait_for(lambda: len(sim.messages("STATUSTEXT")) >= 3, 2.0)
        run.stop()
    odo = [r.msg for r in sim.messages("ODOMETRY")]
    counters = [m.reset_counter for m in odo]
    assert counters == sorted(counters) and set(counters) == {0, 1}
    first_new = counters.index(1)
    assert all(m.reset_counter == 1 for m in (r.msg for r in sim.messages(
        "VISION_POSITION_ESTIMATE")[first_new:]))
    # nothing was sent while lost: a gap of 11 frame periods (lost frames + the new anchor)
    gap = (odo[first_new].time_usec - odo[first_new - 1].time_usec) / 1e6
    assert gap > 10 / 30
    # the new map continues from the last pose sent (the jump is only the missed motion)
    before = np.array([odo[first_new - 1].x, odo[first_new - 1].y, odo[first_new - 1].z])
    after = np.array([odo[first_new].x, odo[first_new].y, odo[first_new].z])
    assert np.linalg.norm(after - before) < 0.1
    texts = [r.msg.text for r in sim.messages("STATUSTEXT")]
    assert "VIO: tracking lost" in texts and "VIO: new map, reset 1" in texts
    lost = [r.msg for r in sim.messages("STATUSTEXT") if r.msg.text == "VIO: tracking lost"]
    assert lost[0].severity == mavlink2.MAV_SEVERITY_CRITICAL
    statuses = {r.msg.system_status for r in sim.messages("HEARTBEAT")}
    assert mavlink2.MAV_STATE_ACTIVE in statuses


class SlowTracker(FakeTracker):
    """Takes 0.3 s per frame: every pose is older than max_latency_s when it is ready."""

    def process(self, image, t, **extra):
        time.sleep(0.3)
        return super().process(image, t)


def test_stale_poses_are_never_sent():
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url), tracker=SlowTracker())
        assert wait_for(lambda: run.service.stats.skipped_stale >= 4, 5.0)
        time.sleep(0.3)
        run.stop()
    assert sim.messages("ODOMETRY") == []
    assert len(sim.messages("HEARTBEAT")) >= 1
    assert run.service.capture.slot.dropped > 0  # the newest frame is tracked, old ones dropped


def test_camera_loss_is_reported():
    """A source that fails: heartbeat status goes to FLIGHT_TERMINATION and a STATUSTEXT says
    so; the capture thread keeps retrying."""

    class Broken:
        name, camera, live, finite = "broken", None, True, False

        def __init__(self):
            self.opens = 0

        def open(self):
            self.opens += 1
            raise OSError("no such device /dev/video9")

        def close(self):
            pass

    source = Broken()
    with SimAutopilot(configured_options(heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url, camera={"reconnect_min_s": 0.05, "reconnect_max_s": 0.2})
        run = RunningService(cfg, source=source)
        assert wait_for(lambda: any(r.msg.system_status == mavlink2.MAV_STATE_FLIGHT_TERMINATION
                                    for r in sim.messages("HEARTBEAT")), 4.0)
        assert wait_for(lambda: source.opens >= 3, 2.0)  # still retrying
        run.stop()
    assert "VIO: camera lost" in [r.msg.text for r in sim.messages("STATUSTEXT")]


def test_statustext_rate_limit_merges_changes():
    from daemon.statustext import StatusTexts

    sent = []
    texts = StatusTexts(1.0, lambda severity, text: sent.append((severity, text)) or True)
    texts.report("tracking good", 0.0)
    for i, state in enumerate(["tracking weak", "tracking bad", "tracking lost"]):
        texts.report(state, 0.1 + 0.1 * i, severity=2)
    texts.flush(0.5)
    assert sent == [(6, "VIO: tracking good")]
    texts.flush(1.0)
    assert sent[-1] == (2, "VIO: tracking lost") and len(sent) == 2 and texts.merged == 2
    texts.report("tracking lost", 5.0)  # no change: nothing sent
    texts.report("x" * 80, 5.0)
    assert len(sent) == 3 and len(sent[-1][1]) == 50
    offline = StatusTexts(1.0, lambda severity, text: False)
    offline.report("tracking good", 0.0)
    assert offline.pending is not None  # kept until the link takes it
