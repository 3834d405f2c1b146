"""One autopilot is listened to, and its reboots are told from odd stamps (autopilot_watch.py,
boot_clock.py)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_watch import AutopilotWatch, Event, Ignored
from daemon.boot_clock import BootClock, Stamp

OUR_CLOCK = 5000.0  # our monotonic time at the autopilot's boot


def stream(t0: float, t1: float, hz: float = 50.0, boot0: float = 0.0,
           latency: float = 0.005) -> list[tuple[float, float]]:
    """(boot stamp, arrival) at `hz` over the autopilot's boot times t0..t1 (a boot at
    our time boot0 + OUR_CLOCK), with a seeded link delay."""
    rng = np.random.default_rng(int(t0 * 1000) + 7)
    boots = np.arange(t0, t1, 1.0 / hz)
    return [(b, OUR_CLOCK + boot0 + b + latency + rng.uniform(0, 0.02)) for b in boots]


def classify(clock: BootClock, items) -> list[Stamp]:
    return [clock.observe(b, a) for b, a in items]


@pytest.mark.parametrize("shift_s", [-10.0, 60.0, -200.0])
def test_a_few_odd_stamps_are_off_the_clock_and_no_reboot(shift_s):
    clock = BootClock()
    items = stream(100.0, 110.0)
    odd = {200, 201, 230, 260, 261, 262}
    items = [(b + shift_s if i in odd else b, a) for i, (b, a) in enumerate(items)]
    got = classify(clock, items)
    assert [i for i, s in enumerate(got) if s is not Stamp.ON_CLOCK] == sorted(odd)
    assert Stamp.REBOOTED not in got and Stamp.JUMPED not in got


def test_one_stream_stamped_10_s_back_for_5_s_is_ignored_not_a_reboot():
    clock = BootClock()
    good = stream(100.0, 110.0, hz=20)
    bad = [(b - 10.0, a) for b, a in stream(103.0, 108.0, hz=50)]
    items = sorted(good + bad, key=lambda item: item[1])
    got = classify(clock, items)
    assert Stamp.REBOOTED not in got
    assert sum(s is Stamp.OFF_CLOCK for s in got) == len(bad)


def test_odd_stamps_just_ahead_cannot_walk_the_clock_into_a_false_reboot():
    """Every 10th stamp a little further ahead than the last odd one, each within what is
    taken as on the clock from where the previous one left it: the clock must not be walked
    forward until the true stamps look like a restart."""
    items = stream(100.0, 130.0)
    items = [(b + 0.9 * (i // 10) if i % 10 == 5 else b, a) for i, (b, a) in enumerate(items)]
    got = classify(BootClock(), items)
    assert Stamp.REBOOTED not in got and Stamp.JUMPED not in got
    assert got.count(Stamp.OFF_CLOCK) <= len(items) // 10


def test_a_real_reboot_is_recognised_within_two_seconds():
    clock = BootClock()
    classify(clock, stream(100.0, 300.0))
    after = stream(0.0, 5.0, boot0=301.0)  # rebooted: stamps restart from 0
    got = classify(clock, after)
    k = got.index(Stamp.REBOOTED)
    assert 1.0 <= after[k][0] <= 2.0  # recognised 1-2 s into the new boot
    assert all(s is Stamp.OFF_CLOCK for s in got[:k])
    assert all(s is Stamp.ON_CLOCK for s in got[k + 1:])
    assert clock.jump_s < -290


def test_a_reboot_soon_after_boot_is_still_a_reboot():
    clock = BootClock()
    classify(clock, stream(0.0, 1.5))
    got = classify(clock, stream(0.0, 3.0, boot0=1.7))
    assert got.count(Stamp.REBOOTED) == 1


@pytest.mark.parametrize("case", ["link lost 10 s", "our loop stalled 3 s", "first stamp odd"])
def test_gaps_stalls_and_a_bad_first_stamp_are_no_reboot(case):
    clock = BootClock()
    items = stream(100.0, 110.0) + stream(120.0, 125.0)
    if case == "our loop stalled 3 s":  # three seconds of messages read in one burst
        items = [(b, max(a, OUR_CLOCK + 105.0)) if 102.0 <= b < 105.0 else (b, a)
                 for b, a in stream(100.0, 110.0)]
    if case == "first stamp odd":
        items[0] = (items[0][0] + 60.0, items[0][1])
    got = classify(clock, items)
    assert Stamp.REBOOTED not in got and Stamp.JUMPED not in got
    assert sum(s is Stamp.OFF_CLOCK for s in got) <= 1


def test_a_sustained_forward_jump_is_followed_without_a_reboot():
    clock = BootClock()
    classify(clock, stream(100.0, 110.0))
    got = classify(clock, [(b + 3600.0, a) for b, a in stream(110.0, 115.0)])
    assert got.count(Stamp.JUMPED) == 1 and Stamp.REBOOTED not in got


# --- binding ---------------------------------------------------------------------------------

def message(system: int, component: int, kind: str = "ATTITUDE", boot_ms: int = 1000,
            autopilot: int = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            vehicle: int = mavlink2.MAV_TYPE_QUADROTOR) -> object:
    mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
    if kind == "HEARTBEAT":
        msg = mav.heartbeat_encode(vehicle, autopilot, 0, 0, mavlink2.MAV_STATE_STANDBY)
    else:
        msg = mav.attitude_encode(boot_ms, 0.1, 0.0, 0.5, 0, 0, 0)
    return mav.decode(bytearray(msg.pack(mav)))


def test_binds_to_the_first_autopilot_heartbeat_and_ignores_everyone_else(caplog):
    watch = AutopilotWatch(3.0, own=(1, 197))
    caplog.set_level(logging.INFO, logger="sdvl.autopilot")
    assert not watch.receive(message(1, 1), 0.0).accepted  # nothing bound yet
    gcs = message(255, 190, "HEARTBEAT", autopilot=mavlink2.MAV_AUTOPILOT_INVALID,
                  vehicle=mavlink2.MAV_TYPE_GCS)
    assert not watch.receive(gcs, 0.1).accepted and not watch.bound
    verdict = watch.receive(message(1, 1, "HEARTBEAT"), 0.2)
    assert verdict.accepted and verdict.events == [Event.CONNECTED]
    assert (watch.system_id, watch.component_id, watch.flavour) == (1, 1, "ardupilot")
    assert watch.receive(message(1, 1, boot_ms=1200), 0.3).accepted
    for k in range(50):  # a second vehicle streaming its own attitude, and its heartbeat
        assert not watch.receive(message(2, 1, boot_ms=900 + k), 0.3 + 0.02 * k).accepted
    assert not watch.receive(message(2, 1, "HEARTBEAT"), 1.4).accepted
    assert not watch.receive(message(1, 197), 1.5).accepted  # our own echo
    assert watch.ignored[Ignored.OTHER_SOURCE] == 52 and watch.ignored_sources[(2, 1)] == 51
    assert watch.ignored[Ignored.UNBOUND] == 2
    lines = [r.getMessage() for r in caplog.records]
    assert sum("bound to autopilot system 1 component 1" in line for line in lines) == 1
    assert sum("ignoring MAVLink system 2 component 1" in line for line in lines) == 1
    assert not any("component 197" in line and "ignoring" in line for line in lines)


def test_configured_autopilot_is_bound_even_when_another_speaks_first():
    watch = AutopilotWatch(3.0, system_id=2, component_id=0)
    assert not watch.receive(message(1, 1, "HEARTBEAT"), 0.0).accepted
    assert watch.receive(message(2, 1, "HEARTBEAT"), 0.1).accepted
    assert (watch.system_id, watch.component_id) == (2, 1)
    assert not watch.receive(message(1, 1), 0.2).accepted


def test_heartbeat_loss_and_return_and_reboot_events():
    watch = AutopilotWatch(1.0)
    t = 0.0
    for k in range(100):  # 2 s of attitude at 50 Hz with a heartbeat each second
        if k % 50 == 0:
            watch.receive(message(1, 1, "HEARTBEAT"), t)
        watch.receive(message(1, 1, boot_ms=100_000 + 20 * k), t)
        t += 0.02
    assert watch.check(t + 1.5) == [Event.LOST] and watch.check(t + 1.6) == []
    events = watch.receive(message(1, 1, "HEARTBEAT"), t + 2.0).events
    assert events == [Event.RECONNECTED]
    got = [e for k in range(100)
           for e in watch.receive(message(1, 1, boot_ms=20 * k), t + 2.0 + 0.02 * k).events]
    assert got == [Event.REBOOTED] and watch.reboots == 1 and watch.losses == 1
