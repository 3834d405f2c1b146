"""The link-side fault scenarios of issue 28, each a change to a simulated flight's MAVLink
stream during a fault window, plus a seeded fuzz that mixes them all.

A scenario takes the flight, a seeded random generator and the window (flight seconds) and
returns the packets the service receives. Messages keep valid CRCs (mutate.py); what is judged
is whether the service and the fusion believe them.
"""

from __future__ import annotations

import copy
import dataclasses
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from daemon.fusion.sensors import remote_time
from sim import fusion_sim
from sim.faults.harness import FaultScore, Packet, Stream, run_stream, score
from sim.faults.mutate import Packer, mutate_field, mutate_fields, pack_or_none, shift_time

AUTOPILOT = (1, 1)
INTRUDER = (2, 1)  # a second vehicle on the same radio
IMU, ATTITUDE = ("SCALED_IMU", "HIGHRES_IMU", "RAW_IMU"), ("ATTITUDE",)
BARO, RANGE = ("SCALED_PRESSURE", "ALTITUDE"), ("DISTANCE_SENSOR",)
GARBAGE_BYTES = 1 << 20


@dataclass
class Item:
    """One message (or raw bytes) to send at `arrival` (our clock) as `sender`."""

    arrival: float
    msg: object  # a pymavlink message, or bytes sent as they are
    sender: tuple[int, int] = AUTOPILOT
    swap: bool = False  # arrives after the next item instead (fuzz)


def flight_time(item: Item) -> float:
    return item.arrival - fusion_sim.BOOT_OFFSET


def heartbeat(status: int = mavlink2.MAV_STATE_ACTIVE) -> object:
    return mavlink2.MAVLink_heartbeat_message(
        mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, status, 3)


def clean_items(flight: fusion_sim.Flight) -> list[Item]:
    """The flight's sensor messages and the autopilot's 1 Hz HEARTBEAT."""
    end = flight.truth.t[-1]
    beats = [Item(t + fusion_sim.BOOT_OFFSET, heartbeat()) for t in np.arange(0.0, end, 1.0)]
    items = [Item(arrival, msg) for arrival, msg in flight.messages] + beats
    return sorted(items, key=lambda item: item.arrival)


def to_stream(flight: fusion_sim.Flight, items: list[Item], window: tuple[float, float],
              injected: int) -> Stream:
    """Pack every item as its sender (valid CRC, the sender's own sequence numbers)."""
    packers: dict[tuple[int, int], Packer] = {}
    packets = []
    for item in sorted(items, key=lambda item: item.arrival):
        if isinstance(item.msg, bytes):
            packets.append(Packet(item.arrival, item.msg))
            continue
        packer = packers.setdefault(item.sender, Packer(*item.sender))
        data = pack_or_none(packer, item.msg)
        if data is not None:
            packets.append(Packet(item.arrival, data))
    return Stream(flight, packets, window, injected)


def clean_packets(flight: fusion_sim.Flight) -> list[Packet]:
    return to_stream(flight, clean_items(flight), (0.0, 0.0), 0).packets


def _during(items: list[Item], window: tuple[float, float], kinds: tuple[str, ...] | None
            ) -> list[int]:
    return [i for i, item in enumerate(items)
            if window[0] <= flight_time(item) < window[1] and not isinstance(item.msg, bytes)
            and (kinds is None or item.msg.get_type() in kinds)]


def resent_mutated(kinds: tuple[str, ...] | None, share: float = 0.1) -> Callable:
    """`share` of these messages re-sent right after the original with 1-3 fields changed."""
    def make(flight, rng, window):
        items = clean_items(flight)
        chosen = [i for i in _during(items, window, kinds) if rng.random() < share]
        extra = [Item(items[i].arrival + 1e-4, mutate_fields(items[i].msg, rng)) for i in chosen]
        return to_stream(flight, items + extra, window, len(extra))
    return make


def changed_in_place(share: float = 0.1, nan_only: bool = False,
                     field: tuple[str, str] | None = None) -> Callable:
    """`share` of every message changed (1-3 fields), or its numbers made NaN/inf; with `field`
    = (message type, field name), `share` of that type's messages with that field changed."""
    def make(flight, rng, window):
        items = clean_items(flight)
        chosen = [i for i in _during(items, window, field[:1] if field else None)
                  if rng.random() < share]
        for i in chosen:
            msg = items[i].msg
            items[i].msg = (_non_finite(msg, rng) if nan_only
                            else mutate_field(msg, field[1], rng) if field
                            else mutate_fields(msg, rng))
        return to_stream(flight, items, window, len(chosen))
    return make


def stream_fields(flight: fusion_sim.Flight) -> list[tuple[str, str]]:
    """(message type, field name) of every field of the messages in `flight`'s stream."""
    first = {}
    for item in clean_items(flight):
        first.setdefault(item.msg.get_type(), item.msg)
    return [(kind, name) for kind, msg in first.items() for name in msg.fieldnames]


def _non_finite(msg: object, rng: np.random.Generator) -> object:
    out = copy.copy(msg)
    floats = [n for n, k in zip(msg.fieldnames, msg.fieldtypes, strict=True)
              if k in ("float", "double") and not isinstance(getattr(msg, n), list)]
    for name in rng.choice(floats, size=min(len(floats), 2), replace=False) if floats else ():
        setattr(out, str(name), float(rng.choice([np.nan, np.inf, -np.inf])))
    return out


def second_system(flight, rng, window):
    """Another vehicle (system 2) on the same radio streams HEARTBEAT, ATTITUDE, IMU and
    rangefinder: its own survey (higher, another heading), booted 0.2 s after ours."""
    other = fusion_sim.simulate(truth=fusion_sim.survey_flight(climb_m=12.0, yaw_deg=125.0),
                                seed=int(rng.integers(1 << 30)))
    items = clean_items(flight)
    extra = [Item(arrival, shift_time(msg, -0.2), INTRUDER)
             for arrival, msg in other.messages
             if window[0] <= arrival - fusion_sim.BOOT_OFFSET < window[1]
             and msg.get_type() in ATTITUDE + IMU + RANGE]
    extra += [Item(t + fusion_sim.BOOT_OFFSET, heartbeat(), INTRUDER)
              for t in np.arange(*window, 1.0)]
    return to_stream(flight, items + extra, window, len(extra))


def stray_highres(flight, rng, window):
    """One HIGHRES_IMU from the autopilot among its SCALED_IMU stream."""
    items = clean_items(flight)
    t = window[0]
    msg = mavlink2.MAVLink_highres_imu_message(int(t * 1e6), 3.0, 0.0, -9.8, 0, 0, 0, 0, 0, 0,
                                               0, 0, 0, 0, 0b111)
    return to_stream(flight, [*items, Item(t + fusion_sim.BOOT_OFFSET, msg)], window, 1)


def odd_stamps(seconds: float, count: int = 5) -> Callable:
    """`count` stamped messages in the window with their boot stamp `seconds` off (a false
    reboot)."""
    def make(flight, rng, window):
        items = clean_items(flight)
        during = [i for i in _during(items, window, None) if remote_time(items[i].msg)]
        for i in rng.choice(during, size=count, replace=False):
            items[i].msg = shift_time(items[i].msg, seconds)
        return to_stream(flight, items, window, count)
    return make


def landed_while_flying(flight, rng, window):
    """The autopilot says the vehicle is disarmed and on the ground while it flies: every
    HEARTBEAT with ArduCopter's STANDBY and every EXTENDED_SYS_STATE ON_GROUND (an autopilot
    never armed says so; the soak's did for an hour)."""
    items = clean_items(flight)
    landed = mavlink2.MAVLink_extended_sys_state_message(
        mavlink2.MAV_VTOL_STATE_UNDEFINED, mavlink2.MAV_LANDED_STATE_ON_GROUND)
    changed = _during(items, window, ("HEARTBEAT", "EXTENDED_SYS_STATE"))
    for i in changed:
        items[i].msg = (landed if items[i].msg.get_type() == "EXTENDED_SYS_STATE"
                        else heartbeat(mavlink2.MAV_STATE_STANDBY))
    return to_stream(flight, items, window, len(changed))


STARVED_READ_S = 1.0  # a starved companion's loop reads the link this seldom
STARVED_FRAME_EVERY = 30  # its tracker finishes one frame in this many (1 fps at 30 fps)
STARVED_DELAY_S = 1.0  # that long after the frame's capture


def cpu_starved(flight, rng, window):
    """The companion's CPU starved during the window (one core shared with six busy loops):
    its loop reads the link once a second (the packets come in bursts, in order) and its
    tracker finishes one frame in STARVED_FRAME_EVERY, STARVED_DELAY_S after its capture."""
    start, end = (w + fusion_sim.BOOT_OFFSET for w in window)
    packets = [Packet(min(float(np.ceil(p.arrival / STARVED_READ_S)) * STARVED_READ_S, end)
                      if start <= p.arrival < end else p.arrival, p.data)
               for p in clean_packets(flight)]
    frames, starved = [], 0
    for ready, result, t_capture in flight.frames:
        if start <= t_capture < end:
            starved += 1
            if starved % STARVED_FRAME_EVERY:
                continue
            ready = t_capture + STARVED_DELAY_S
        frames.append((ready, result, t_capture))
    return Stream(dataclasses.replace(flight, frames=sorted(frames, key=lambda f: f[0])),
                  sorted(packets, key=lambda p: p.arrival), window, 0)


def garbage(flight, rng, window):
    """1 MB of random bytes spread over the window, between the packets."""
    items = clean_items(flight)
    sizes = rng.integers(1, 2000, size=GARBAGE_BYTES // 1000)
    times = np.sort(rng.uniform(*window, size=len(sizes))) + fusion_sim.BOOT_OFFSET
    extra = [Item(t, rng.bytes(int(n))) for t, n in zip(times, sizes, strict=True)]
    return to_stream(flight, items + extra, window, len(extra))


def link_loss(flight, rng, window):
    """Nothing arrives during the window."""
    items = [item for item in clean_items(flight)
             if not window[0] <= flight_time(item) < window[1]]
    return to_stream(flight, items, window, 0)


def reboot(flight, rng, window):
    """The autopilot reboots at the window's start, is silent for 2 s, then streams again
    with its boot clock restarted (the window's end is when it is back)."""
    items = []
    for item in clean_items(flight):
        t = flight_time(item)
        if window[0] <= t < window[0] + 2.0:
            continue
        if t >= window[0]:
            item.msg = shift_time(item.msg, -window[0])
        items.append(item)
    return to_stream(flight, items, (window[0], window[0] + 2.0), 0)


FUZZ_KINDS = ("fields", "stamp", "sender", "duplicate", "drop", "swap", "garbage", "random")


def fuzz(share: float, kinds: tuple[str, ...] = FUZZ_KINDS) -> Callable:
    """A seeded mix of faults (`kinds`, default all), on `share` of the messages in the window:
    fields changed, stamps moved, another sender, duplicated, dropped, swapped with the next,
    garbage bytes, a random message of a kind the fusion reads."""
    def make(flight, rng, window):
        items = clean_items(flight)
        chosen = set(i for i in _during(items, window, None) if rng.random() < share)
        out, injected = [], 0
        for i, item in enumerate(items):
            if i not in chosen:
                out.append(item)
                continue
            injected += 1
            out += _fuzzed(item, str(rng.choice(kinds)), rng)
        for k in range(len(out) - 1):  # swapped arrivals: the later one first
            if out[k].swap:
                out[k].arrival, out[k + 1].arrival = out[k + 1].arrival, out[k].arrival
        return to_stream(flight, out, window, injected)
    return make


def _fuzzed(item: Item, kind: str, rng: np.random.Generator) -> list[Item]:
    msg = item.msg
    if kind == "fields":
        return [Item(item.arrival, mutate_fields(msg, rng))]
    if kind == "stamp":
        seconds = float(rng.choice([-60.0, -10.0, -1.5, 1.5, 10.0, 60.0, -1e6]))
        return [Item(item.arrival, shift_time(msg, seconds))]
    if kind == "sender":
        sender = tuple(rng.choice([(2, 1), (1, 197), (255, 190), (1, 2)]))
        return [Item(item.arrival, msg, sender)]
    if kind == "duplicate":
        return [item, Item(item.arrival + 1e-4, msg)]
    if kind == "drop":
        return []
    if kind == "swap":
        item.swap = True
        return [item]
    if kind == "garbage":
        return [item, Item(item.arrival + 1e-4, rng.bytes(int(rng.integers(1, 300))))]
    return [item, Item(item.arrival + 1e-4, _random_message(msg, rng))]


def _random_message(like: object, rng: np.random.Generator) -> object:
    """A message of a kind the fusion reads, stamped like `like`, every other field mutated."""
    template = {
        "ATTITUDE": mavlink2.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0),
        "SCALED_IMU": mavlink2.MAVLink_scaled_imu_message(0, 0, 0, -1000, 0, 0, 0, 0, 0, 0),
        "HIGHRES_IMU": mavlink2.MAVLink_highres_imu_message(
            0, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 1013, 0, 0, 20, 0xFFFF),
        "DISTANCE_SENSOR": mavlink2.MAVLink_distance_sensor_message(
            0, 10, 4000, 500, 0, 0, mavlink2.MAV_SENSOR_ROTATION_PITCH_270, 0),
        "SCALED_PRESSURE": mavlink2.MAVLink_scaled_pressure_message(0, 1000.0, 0.0, 2000),
        "ALTITUDE": mavlink2.MAVLink_altitude_message(0, 100, 100, 100, 10, 10, 10),
    }[str(rng.choice(["ATTITUDE", "SCALED_IMU", "HIGHRES_IMU", "DISTANCE_SENSOR",
                      "SCALED_PRESSURE", "ALTITUDE"]))]
    msg = mutate_fields(template, rng, count=len(template.fieldnames) - 1)
    boot_ms = getattr(like, "time_boot_ms", None)
    if boot_ms is not None:
        for name, scale in (("time_boot_ms", 1), ("time_usec", 1000)):
            if hasattr(msg, name):
                setattr(msg, name, boot_ms * scale)
    return msg


SCENARIOS: dict[str, Callable] = {
    "imu-mutated": resent_mutated(IMU),
    "attitude-mutated": resent_mutated(ATTITUDE),
    "baro-mutated": resent_mutated(BARO),
    "rangefinder-mutated": resent_mutated(RANGE),
    "all-mutated": changed_in_place(0.1),
    "nan-values": changed_in_place(0.1, nan_only=True),
    "second-system": second_system,
    "stray-highres-imu": stray_highres,
    "false-reboot-10s-back": odd_stamps(-10.0),
    "false-reboot-60s-ahead": odd_stamps(60.0),
    "landed-while-flying": landed_while_flying,
    "cpu-starved": cpu_starved,
    "garbage-1mb": garbage,
    "link-loss-5s": link_loss,
    "reboot": reboot,
    "fuzz-30%": fuzz(0.3),
}
WINDOW_S = {"second-system": 5.0, "link-loss-5s": 5.0, "false-reboot-10s-back": 5.0,
            "false-reboot-60s-ahead": 5.0}


def run_scenarios(flight: fusion_sim.Flight, names: list[str], seed: int,
                  window: tuple[float, float] = (30.0, 40.0), filtered: bool = True
                  ) -> list[FaultScore]:
    """Each named scenario on `flight` with the fault from window[0] (for WINDOW_S or the
    window's length), scored against the same flight without faults. `filtered=False` hands
    every message to the estimator as the service did before it bound one autopilot."""
    clean = run_stream(Stream(flight, clean_packets(flight), (0.0, 0.0), 0), filtered)
    scores = []
    for name in names:
        rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
        length = WINDOW_S.get(name, window[1] - window[0])
        stream = SCENARIOS[name](flight, rng, (window[0], window[0] + length))
        scores.append(score(name, stream, run_stream(stream, filtered), clean))
    return scores
