"""The stream keeper against scripted autopilots on a virtual clock: what it asks for, how it
falls back, when it asks again, and the parameter it names when a stream stays missing."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import pytest
from daemon_helpers import RunningService, service_config, wait_for
from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_params import wire_value
from daemon.stream_groups import (
    ARDUPILOT_GROUPS,
    DATA_STREAM_IDS,
    ardupilot_rate_params,
    needs_for,
    stream_hints,
)
from daemon.streams import ACK_TIMEOUT_S, SETTLE_S, WINDOW_S, StreamKeeper
from sim.autopilot import SimAutopilot, SimOptions

MSG_ID = {name: getattr(mavlink2, f"MAVLINK_MSG_ID_{name}")
          for name in ("ATTITUDE", "RAW_IMU", "SCALED_PRESSURE", "DISTANCE_SENSOR",
                       "LOCAL_POSITION_NED", "HIGHRES_IMU", "ALTITUDE", "EXTENDED_SYS_STATE")}
NAME_OF = {v: k for k, v in MSG_ID.items()}
INT8, REAL32 = mavlink2.MAV_PARAM_TYPE_INT8, mavlink2.MAV_PARAM_TYPE_REAL32


@dataclass
class Watch:
    """What the keeper reads of daemon.autopilot_watch.AutopilotWatch."""

    flavour: str = "ardupilot"
    system_id: int = 1
    component_id: int = 1
    alive: bool = True
    reboots: int = 0
    losses: int = 0


class Codec:
    """Records what the keeper sends."""

    def __init__(self):
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=197)
        self.sent: list = []

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def of(self, kind: str, command: int | None = None) -> list:
        return [m for m in self.sent if m.get_type() == kind
                and (command is None or m.command == command)]


class Autopilot:
    """Builds messages as the autopilot (system 1) sends them."""

    def __init__(self, flavour: str = "ardupilot"):
        self.flavour = flavour
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink2.MAVLink(None)

    def wire(self, msg):
        return self.parser.parse_buffer(msg.pack(self.mav))[0]

    def ack(self, result: int):
        return self.wire(self.mav.command_ack_encode(
            mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, result, 0, 0, 1, 197))

    def param(self, name: str, value: float, kind: int = INT8):
        return self.wire(self.mav.param_value_encode(
            name.encode(), wire_value(self.flavour, value, kind), kind, 900, 0))

    def stream(self, name: str):
        build = {"ATTITUDE": lambda: self.mav.attitude_encode(0, 0, 0, 0, 0, 0, 0),
                 "RAW_IMU": lambda: self.mav.raw_imu_encode(0, 0, 0, -1000, 0, 0, 0, 0, 0, 0),
                 "SCALED_PRESSURE": lambda: self.mav.scaled_pressure_encode(0, 1000, 0, 2000),
                 "HIGHRES_IMU": lambda: self.mav.highres_imu_encode(
                     0, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 1000, 0, 0, 0, 0b1000000111),
                 "ALTITUDE": lambda: self.mav.altitude_encode(0, 1, 1, 1, 1, 1, 1),
                 "EXTENDED_SYS_STATE": lambda: self.mav.extended_sys_state_encode(0, 1)}[name]
        return self.wire(build())


def run(keeper: StreamKeeper, autopilot: Autopilot, t0: float, t1: float,
        answer=None, streams: dict[str, float] | None = None, step: float = 0.01) -> float:
    """Tick from t0 to t1; `answer(command) -> ACK result or None` answers each new
    SET_MESSAGE_INTERVAL; `streams` name -> Hz arrive meanwhile."""
    answered = len(keeper.codec.of("COMMAND_LONG"))
    next_at = dict.fromkeys(streams or {}, t0)
    t = t0
    while t < t1:
        keeper.tick(t)
        commands = keeper.codec.of("COMMAND_LONG")
        for command in commands[answered:]:
            result = answer(command) if answer else None
            if result is not None:
                keeper.on_message(autopilot.ack(result), t)
        answered = len(commands)
        for name, hz in (streams or {}).items():
            if t >= next_at[name]:
                keeper.on_message(autopilot.stream(name), t)
                next_at[name] += 1.0 / hz
        t += step
    return t


def accept_all(_command):
    return mavlink2.MAV_RESULT_ACCEPTED


def test_asks_for_each_need_one_at_a_time_and_reports_nothing_when_all_arrive():
    codec, reports = Codec(), []
    keeper = StreamKeeper(codec, Watch(), usb=False, report=lambda *a: reports.append(a))
    streams = {"ATTITUDE": 50, "RAW_IMU": 50, "SCALED_PRESSURE": 10}
    run(keeper, Autopilot(), 0.0, 8.0, accept_all, streams)
    asks = codec.of("COMMAND_LONG", mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert [NAME_OF[int(c.param1)] for c in asks] == [
        "ATTITUDE", "RAW_IMU", "SCALED_PRESSURE", "DISTANCE_SENSOR", "LOCAL_POSITION_NED"]
    assert [c.param2 for c in asks] == [1e6 / 50, 1e6 / 50, 1e6 / 10, 1e6 / 20, 1e6 / 10]
    assert all((c.target_system, c.target_component) == (1, 1) for c in asks)
    assert not codec.of("REQUEST_DATA_STREAM")
    assert reports == []  # no rangefinder and no position yet are not faults
    status = keeper.statuses
    assert status["attitude"].rate_hz == pytest.approx(50, abs=1)
    assert status["IMU"].usable and status["barometer"].usable
    assert not status["downward rangefinder"].usable


def test_refused_ardupilot_is_asked_for_the_stream_group():
    codec = Codec()
    keeper = StreamKeeper(codec, Watch(), usb=False)
    run(keeper, Autopilot(), 0.0, 3.0, lambda c: mavlink2.MAV_RESULT_UNSUPPORTED)
    groups = {(m.req_stream_id, m.req_message_rate, m.start_stop)
              for m in codec.of("REQUEST_DATA_STREAM")}
    assert groups == {(mavlink2.MAV_DATA_STREAM_EXTRA1, 50, 1),
                      (mavlink2.MAV_DATA_STREAM_RAW_SENSORS, 50, 1),
                      (mavlink2.MAV_DATA_STREAM_RAW_SENSORS, 10, 1),
                      (mavlink2.MAV_DATA_STREAM_EXTRA3, 20, 1),
                      (mavlink2.MAV_DATA_STREAM_POSITION, 10, 1)}
    assert keeper.statuses["attitude"].method == "REQUEST_DATA_STREAM EXTRA1"


def test_silent_px4_is_asked_twice_then_left_to_its_mode():
    codec = Codec()
    keeper = StreamKeeper(codec, Watch(flavour="px4"), usb=False)
    run(keeper, Autopilot("px4"), 0.0, 6 * 2 * ACK_TIMEOUT_S + 0.5)
    asks = codec.of("COMMAND_LONG", mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL)
    names = [NAME_OF[int(c.param1)] for c in asks]
    assert names == [n for n in ("ATTITUDE", "HIGHRES_IMU", "ALTITUDE", "DISTANCE_SENSOR",
                                 "LOCAL_POSITION_NED", "EXTENDED_SYS_STATE") for _ in range(2)]
    assert not codec.of("REQUEST_DATA_STREAM")  # PX4 does not implement it
    assert keeper.statuses["IMU"].answer.value == "no answer"
    assert "MAV_n_MODE" in keeper.statuses["IMU"].method


def answer_params(keeper: StreamKeeper, autopilot: Autopilot, values: dict, t: float) -> None:
    """Answer the keeper's PARAM_REQUEST_READs for the names in `values`."""
    for request in keeper.codec.of("PARAM_REQUEST_READ"):
        name = request.param_id
        if name in values:
            keeper.on_message(autopilot.param(name, values[name]), t)


AP47 = {"MAV1_EXTRA1": 4, "SERIAL0_PROTOCOL": 2, "SERIAL1_PROTOCOL": 2, "SERIAL2_PROTOCOL": 2,
        "SERIAL3_PROTOCOL": 5}


@pytest.mark.parametrize(("params", "usb", "names"), [
    (AP47, False, ["MAV2_EXTRA1", "MAV3_EXTRA1"]),
    ({**AP47, "SERIAL1_PROTOCOL": 5}, False, ["MAV2_EXTRA1"]),  # SERIAL2 is the 2nd MAVLink port
    (AP47, True, ["MAV1_EXTRA1"]),
    ({"SR0_EXTRA1": 4, "SERIAL1_PROTOCOL": 2, "SERIAL2_PROTOCOL": 2}, False,
     ["SR1_EXTRA1", "SR2_EXTRA1"]),
])
def test_missing_attitude_names_the_parameter_this_ardupilot_has(params, usb, names, caplog):
    caplog.set_level(logging.WARNING, logger="sdvl.streams")
    codec, reports, autopilot = Codec(), [], Autopilot()
    keeper = StreamKeeper(codec, Watch(), usb=usb, report=lambda *a: reports.append(a))
    streams = {"RAW_IMU": 50, "SCALED_PRESSURE": 10}
    t = run(keeper, autopilot, 0.0, SETTLE_S + 0.5, accept_all, streams)
    assert codec.of("PARAM_REQUEST_READ") and not reports  # reads first, then says
    answer_params(keeper, autopilot, params, t)
    run(keeper, autopilot, t, t + 2.0, accept_all, streams)
    fix = f"{names[0]}=50" if len(names) == 1 else " or ".join(names)
    assert reports == [(f"no ATTITUDE: set {fix}", mavlink2.MAV_SEVERITY_WARNING)]
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and lines[0].startswith(
        "ATTITUDE (attitude) arrives at 0.0 Hz, the service needs 10 Hz (asked for 50 Hz with "
        "SET_MESSAGE_INTERVAL: accepted)")
    for name in names:
        assert f"{name} = 50" in lines[0]


def test_missing_px4_imu_names_the_instance_mode():
    codec, reports, autopilot = Codec(), [], Autopilot("px4")
    keeper = StreamKeeper(codec, Watch(flavour="px4"), usb=False,
                          report=lambda *a: reports.append(a))
    streams = {"ATTITUDE": 50, "ALTITUDE": 10, "EXTENDED_SYS_STATE": 5}
    t = run(keeper, autopilot, 0.0, SETTLE_S + 0.5, accept_all, streams)
    answer_params(keeper, autopilot, {"MAV_0_MODE": 0, "MAV_0_CONFIG": 0, "MAV_1_MODE": 7,
                                      "MAV_1_CONFIG": 102}, t)
    run(keeper, autopilot, t, t + 2.0, accept_all, streams)
    assert reports == [("no HIGHRES_IMU: set MAV_1_MODE=2", mavlink2.MAV_SEVERITY_WARNING)]


def test_asks_again_after_a_reboot_and_after_a_silence():
    codec, watch, autopilot = Codec(), Watch(), Autopilot()
    keeper = StreamKeeper(codec, watch, usb=False, report=lambda *a: None)
    streams = {"ATTITUDE": 50, "RAW_IMU": 50, "SCALED_PRESSURE": 10}
    t = run(keeper, autopilot, 0.0, 12.0, accept_all, streams)
    assert keeper.restarts == 1
    watch.reboots = 1
    t = run(keeper, autopilot, t, t + 1.0, accept_all, streams)
    assert keeper.restarts == 2
    t = run(keeper, autopilot, t, t + 12.0, accept_all, streams)
    quiet = {"RAW_IMU": 50, "SCALED_PRESSURE": 10}  # ATTITUDE stopped (a reboot not seen)
    run(keeper, autopilot, t, t + 4.0, accept_all, quiet)
    assert keeper.restarts == 3
    asks = codec.of("COMMAND_LONG", mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert [NAME_OF[int(c.param1)] for c in asks].count("ATTITUDE") == 3


def test_release_puts_the_default_rates_back():
    codec = Codec()
    keeper = StreamKeeper(codec, Watch(), usb=False)
    run(keeper, Autopilot(), 0.0, 1.0, accept_all)
    codec.sent.clear()
    keeper.release()
    assert [(NAME_OF[int(c.param1)], c.param2) for c in codec.sent] == [
        (n.request, 0) for n in needs_for("ardupilot")]


def test_every_ardupilot_need_has_a_stream_group():
    for need in needs_for("ardupilot"):
        assert ARDUPILOT_GROUPS[need.request] in DATA_STREAM_IDS
    assert ardupilot_rate_params("EXTRA3", {}, usb=False) == [("MAV1_EXTRA3", 0)]
    assert [str(h) for h in stream_hints("ardupilot", needs_for("ardupilot")[0], AP47, True)] \
        == ["MAV1_EXTRA1 = 50 (if the companion is on SERIAL0)"]


def test_the_service_gets_its_streams_from_a_fresh_ardupilot_and_again_after_a_reboot():
    """A fresh ArduCopter streams nothing on the companion's port (autopilot-interface.md (e)
    1): the service asks for each need when the heartbeat comes, gets them, and asks again
    after the autopilot reboots (which forgets what was asked)."""
    wanted = [n.request for n in needs_for("ardupilot")]

    def asked(since: float) -> list[str]:
        return [NAME_OF[int(r.msg.param1)] for r in sim.messages("COMMAND_LONG", since)
                if r.msg.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL]

    def flowing() -> bool:
        status = run.service.streams.statuses
        return bool(status) and all(status[k].usable for k in ("attitude", "IMU", "barometer"))

    with SimAutopilot(SimOptions(heartbeat_hz=5)) as sim:
        run = RunningService(service_config(sim.url, mavlink={"heartbeat_timeout_s": 0.6}))
        try:
            assert wait_for(flowing, 10.0), asked(0.0)
            assert asked(0.0)[:len(wanted)] == wanted
            t_reboot, restarts = time.monotonic(), run.service.streams.restarts
            sim.reboot(downtime_s=1.0)
            assert wait_for(lambda: set(asked(t_reboot + 1.0)) == set(wanted), 10.0)
            assert run.service.streams.restarts > restarts
            time.sleep(WINDOW_S + 0.5)  # rates counted after the reboot only
            assert flowing()
        finally:
            run.stop()
    assert sim.sent_count.get("ATTITUDE", 0) > 100


def test_a_dead_stream_is_asked_for_again_but_reported_once():
    codec, reports, autopilot = Codec(), [], Autopilot()
    keeper = StreamKeeper(codec, Watch(), usb=False, report=lambda *a: reports.append(a))
    t = run(keeper, autopilot, 0.0, 12.0, accept_all, {"ATTITUDE": 50, "RAW_IMU": 50,
                                                       "SCALED_PRESSURE": 10})
    t = run(keeper, autopilot, t, t + 4.0, accept_all, {"ATTITUDE": 50, "RAW_IMU": 50})
    answer_params(keeper, autopilot, AP47, t)
    run(keeper, autopilot, t, t + 40.0, accept_all, {"ATTITUDE": 50, "RAW_IMU": 50})
    assert keeper.restarts >= 3  # the barometer is asked for again every REASK_MIN_S
    assert reports == [("no SCALED_PRESSURE: set MAVn_RAW_SENS", mavlink2.MAV_SEVERITY_WARNING)]


def test_arrivals_of_a_stream_no_need_rates_stay_bounded():
    """An ArduPilot streaming PX4's HIGHRES_IMU (tracked for PX4, never rated for ArduPilot):
    its arrival times must not pile up for the service's lifetime."""
    keeper = StreamKeeper(Codec(), Watch(), usb=False)
    autopilot = Autopilot()
    for k in range(5000):  # 100 s at 50 Hz
        keeper.on_message(autopilot.stream("HIGHRES_IMU"), 0.02 * k)
    assert len(keeper.arrivals["HIGHRES_IMU"]) <= WINDOW_S / 0.02 + 1


def test_rates_measured_while_the_loop_was_held_up_blame_no_autopilot(caplog):
    """A starved CPU: the loop ticks 0.8 s late and reads 1 of 5 ATTITUDE messages; that is not
    the autopilot's stream rate, so no parameter is named until the loop keeps up again."""
    reports = []
    keeper = StreamKeeper(Codec(), Watch(), usb=False, report=lambda *a: reports.append(a))
    autopilot = Autopilot()
    all_streams = {"ATTITUDE": 50, "RAW_IMU": 50, "SCALED_PRESSURE": 10}
    t = run(keeper, autopilot, 0.0, 6.0, accept_all, all_streams)
    caplog.set_level(logging.WARNING)
    for _ in range(10):  # 8 s held up: a tick every 0.8 s, a few messages each
        t += 0.8
        for name in all_streams:
            keeper.on_message(autopilot.stream(name), t)
        keeper.tick(t)
    assert not [r for r in reports if "ATTITUDE" in r[0]]
    assert sum("held up" in r.getMessage() for r in caplog.records) == 1
    run(keeper, autopilot, t, t + 20.0, accept_all, {"RAW_IMU": 50, "SCALED_PRESSURE": 10})
    assert [r for r in reports if "ATTITUDE" in r[0]]  # kept up again: a real outage is said


def test_a_rate_just_under_its_floor_is_said_once(caplog):
    """RAW_IMU at 19.75 Hz against a 20 Hz floor, counted over 2 s windows, is 19.5 or 20 Hz in
    turn (the hour-long soak said it 104 times): said once; again only after it was clearly
    back, and not within a minute of the last time."""
    reports, autopilot = [], Autopilot()
    keeper = StreamKeeper(Codec(), Watch(), usb=False, report=lambda *a: reports.append(a))
    others = {"ATTITUDE": 50, "SCALED_PRESSURE": 10}
    caplog.set_level(logging.INFO)

    def imu_reports(t0: float, t1: float, hz: float) -> int:
        run(keeper, autopilot, t0, t1, accept_all, {**others, "RAW_IMU": hz}, step=0.02)
        return sum("RAW_IMU" in text for text, _ in reports)

    assert imu_reports(0.0, 10.0, 50) == 0
    assert imu_reports(10.0, 310.0, 19.75) == 1
    assert imu_reports(310.0, 320.0, 21) == 1  # above the floor, not clearly: no news
    assert not [r for r in caplog.records if "arrives again" in r.getMessage()]
    assert imu_reports(320.0, 330.0, 50) == 1
    assert [r for r in caplog.records if "RAW_IMU arrives again" in r.getMessage()]
    assert imu_reports(330.0, 350.0, 10) == 2  # back and gone again: said again
    run(keeper, autopilot, 350.0, 360.0, accept_all, {**others, "RAW_IMU": 50}, step=0.02)
    assert imu_reports(360.0, 385.0, 10) == 2  # and once more, but not within a minute
    assert imu_reports(385.0, 420.0, 10) == 3
