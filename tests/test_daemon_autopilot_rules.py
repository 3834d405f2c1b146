"""check-autopilot's rules on their own: parameters (ArduPilot, PX4), what was heard on the
link, the delay each autopilot needs, and the parameter protocol client."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from daemon_helpers import FakeTracker
from pymavlink.dialects.v20 import common as mavlink2

from daemon.ardupilot_params import ardupilot_findings, ardupilot_position_error
from daemon.autopilot_params import CheckContext, Severity, needs_reboot, wire_value
from daemon.autopilot_probe import Probe
from daemon.camera import TestPatternSource
from daemon.config import Config, replace
from daemon.latency import ardupilot_delay_ms, measure_capture_to_send, px4_delay_ms
from daemon.param_client import ParamClient
from daemon.probe_findings import probe_findings
from daemon.px4_params import px4_findings
from daemon.stream_groups import needs_for
from daemon.streams import Answer, StreamStatus

# an ArduPilot set up as check-autopilot recommends (4.7 names)
GOOD = {"AHRS_EKF_TYPE": 3, "EK3_ENABLE": 1, "VISO_TYPE": 2, "VISO_ORIENT": 0, "VISO_SCALE": 1,
        "VISO_POS_X": 0, "VISO_POS_Y": 0, "VISO_POS_Z": 0, "VISO_QUAL_MIN": 0,
        "VISO_POS_M_NSE": 0.1, "VISO_YAW_M_NSE": 0.2, "VISO_DELAY_MS": 35,
        "EK3_SRC1_POSXY": 6, "EK3_SRC1_VELXY": 6, "EK3_SRC1_POSZ": 1, "EK3_SRC1_VELZ": 6,
        "EK3_SRC1_YAW": 1, "COMPASS_USE": 1, "GPS1_TYPE": 0, "ARMING_SKIPCHK": 0}
CTX = CheckContext(delay_ms=35, delay_basis="measured", gps_present=False, origin_enabled=True)


def by_name(findings) -> dict:
    return {f.name: f for f in findings}


def test_a_recommended_ardupilot_has_nothing_to_fix():
    findings = ardupilot_findings(GOOD, CTX)
    assert [f.severity for f in findings] == [Severity.NOTE] * 2
    assert "sends from power-on" in by_name(findings)["arming"].message
    assert by_name(findings)["VISO_DELAY_MS"].message.startswith("right within 10 ms")


@pytest.mark.parametrize(("viso", "severity", "words"), [
    (0, Severity.ERROR, "ignores vision messages"),
    (1, Severity.WARNING, "catches a wrong camera mounting"),
    (3, Severity.WARNING, "that record is (0,0,0) after every autopilot boot"),
    (7, Severity.ERROR, "not a type this service works with"),
])
def test_viso_type_2_is_recommended_and_why(viso, severity, words):
    f = by_name(ardupilot_findings({**GOOD, "VISO_TYPE": viso}, CTX))["VISO_TYPE"]
    assert (f.severity, f.set_to) == (severity, 2)
    assert words in f.message and f.message.endswith("(reboot)")


def test_firmware_without_visual_odometry_or_ekf_sources():
    p = {k: v for k, v in GOOD.items() if not k.startswith(("VISO", "EK3_SRC"))}
    found = by_name(ardupilot_findings(p, CTX))
    assert found["VISO_TYPE"].value is None and "custom.ardupilot.org" in found["VISO_TYPE"].message
    assert "older than 4.1" in found["EK3_SRC1_POSXY"].message


@pytest.mark.parametrize(("gps_name", "present", "severity"), [
    ("GPS1_TYPE", False, Severity.ERROR), ("GPS_TYPE", False, Severity.ERROR),
    ("GPS1_TYPE", None, Severity.NOTE)])
def test_gps_type_by_the_name_this_firmware_has(gps_name, present, severity):
    p = {k: v for k, v in GOOD.items() if k != "GPS1_TYPE"} | {gps_name: 1}
    f = by_name(ardupilot_findings(p, CheckContext(gps_present=present)))[gps_name]
    assert f.severity == severity
    assert f.set_to == (0 if severity == Severity.ERROR else None)


def test_without_gps_the_service_must_set_the_origin():
    found = by_name(ardupilot_findings(GOOD, CheckContext(origin_enabled=False)))
    assert found["origin.enabled"].severity == Severity.ERROR
    assert "origin.enabled" not in by_name(ardupilot_findings(
        {**GOOD, "GPS1_TYPE": 1}, CheckContext(gps_present=True, origin_enabled=False)))


@pytest.mark.parametrize(("name", "value", "set_to"), [
    ("ARMING_SKIPCHK", 1 << 18, 0), ("ARMING_SKIPCHK", -1, -1 & ~(1 << 18)),
    ("ARMING_CHECK", 0, 1), ("ARMING_CHECK", 2, 2 | 1 << 18)])
def test_the_visual_odometry_arming_check_must_stay_on(name, value, set_to):
    p = {k: v for k, v in GOOD.items() if k != "ARMING_SKIPCHK"} | {name: value}
    f = by_name(ardupilot_findings(p, CTX))[name]
    assert (f.severity, f.set_to) == (Severity.WARNING, set_to)
    for fine in ({"ARMING_CHECK": 1}, {"ARMING_CHECK": 1 << 18}, {"ARMING_SKIPCHK": 4}):
        p = {k: v for k, v in GOOD.items() if k != "ARMING_SKIPCHK"} | fine
        assert not {"ARMING_CHECK", "ARMING_SKIPCHK"} & set(by_name(ardupilot_findings(p, CTX)))


def test_yaw_sources():
    assert by_name(ardupilot_findings({**GOOD, "EK3_SRC1_YAW": 6}, CTX))["EK3_SRC1_YAW"].set_to \
        == 1
    gps_yaw = ardupilot_findings({**GOOD, "EK3_SRC1_YAW": 2, "GPS1_TYPE": 1},
                                 CheckContext(gps_present=True, delay_ms=35))
    assert "EK3_SRC1_YAW" not in by_name(gps_yaw)
    no_compass = by_name(ardupilot_findings({**GOOD, "COMPASS_USE": 0}, CTX))
    assert no_compass["COMPASS_USE"].severity == Severity.ERROR


def test_noise_floor_and_lever_arm():
    new, old = ardupilot_position_error(0.05)
    assert new == pytest.approx(np.sqrt(3 * 0.05**2))
    assert old == pytest.approx((3 * 0.05**4) ** (1 / 3))
    found = by_name(ardupilot_findings({**GOOD, "VISO_POS_M_NSE": 0.2, "VISO_POS_X": 0.1}, CTX))
    assert found["VISO_POS_M_NSE"].set_to == 0.1 and "0.087 m (4.7+)" in \
        found["VISO_POS_M_NSE"].message
    assert found["VISO_POS_X"].set_to == 0
    passthrough = CheckContext(fusion=False, delay_ms=35, gps_present=False, origin_enabled=True)
    assert "VISO_POS_X" not in by_name(ardupilot_findings({**GOOD, "VISO_POS_X": 0.1},
                                                          passthrough))


def test_quality_gate_depends_on_the_message():
    vpe = CheckContext(output="vision_position", delay_ms=35, gps_present=False)
    assert by_name(ardupilot_findings({**GOOD, "VISO_QUAL_MIN": 10}, vpe))[
        "VISO_QUAL_MIN"].severity == Severity.ERROR
    assert by_name(ardupilot_findings({**GOOD, "VISO_QUAL_MIN": -1}, CTX))[
        "VISO_QUAL_MIN"].severity == Severity.WARNING


@pytest.mark.parametrize(("delay", "measured", "expect"), [
    (35, 40, None), (10, 62, 62), (10, None, "not checked"), (10, 400, 250)])
def test_delay_against_what_was_measured(delay, measured, expect):
    ctx = CheckContext(delay_ms=measured, gps_present=False, origin_enabled=True)
    f = by_name(ardupilot_findings({**GOOD, "VISO_DELAY_MS": delay}, ctx)).get("VISO_DELAY_MS")
    if expect is None:
        assert f.severity == Severity.NOTE and f.set_to is None
    elif expect == "not checked":
        assert f.severity == Severity.NOTE and "not checked" in f.message
    else:
        assert (f.severity, f.set_to) == (Severity.WARNING, expect)


PX4_GOOD = {"EKF2_EV_CTRL": 7, "EKF2_HGT_REF": 0, "EKF2_EV_DELAY": 0, "EKF2_EV_NOISE_MD": 0,
            "EKF2_EV_QMIN": 0, "EKF2_EVP_NOISE": 0.05, "EKF2_EVA_NOISE": 0.1,
            "EKF2_EV_POS_X": 0, "EKF2_EV_POS_Y": 0, "EKF2_EV_POS_Z": 0}


@pytest.mark.parametrize(("changes", "output", "name", "severity", "set_to"), [
    ({"EKF2_EV_CTRL": 0}, "odometry", "EKF2_EV_CTRL", Severity.ERROR, 1),
    ({"EKF2_EV_CTRL": 15}, "odometry", "EKF2_EV_CTRL", Severity.ERROR, 7),
    ({"EKF2_EV_CTRL": 5}, "vision_position", "EKF2_EV_CTRL", Severity.WARNING, 1),
    ({"EKF2_EV_CTRL": 5, "EKF2_HGT_REF": 3}, "odometry", "EKF2_EV_CTRL", Severity.ERROR, 7),
    ({"EKF2_EV_NOISE_MD": 1}, "odometry", "EKF2_EV_NOISE_MD", Severity.WARNING, 0),
    ({"EKF2_EVP_NOISE": 0.1}, "odometry", "EKF2_EVP_NOISE", Severity.WARNING, 0.05),
    ({"EKF2_EV_QMIN": 10}, "vision_position", "EKF2_EV_QMIN", Severity.ERROR, 0),
    ({"EKF2_EV_POS_Z": -0.1}, "odometry", "EKF2_EV_POS_Z", Severity.WARNING, 0),
    ({"EKF2_EV_DELAY": 40}, "odometry", "EKF2_EV_DELAY", Severity.WARNING, 0),
])
def test_px4_rules(changes, output, name, severity, set_to):
    ctx = CheckContext(output=output, delay_ms=0)
    good = PX4_GOOD if output == "odometry" else {**PX4_GOOD, "EKF2_EV_CTRL": 3}
    assert [f.severity for f in px4_findings(good, ctx)] == [Severity.NOTE]  # the delay is right
    f = by_name(px4_findings({**good, **changes}, ctx))[name]
    assert (f.severity, f.set_to) == (severity, set_to)


def test_which_parameters_need_a_reboot():
    assert needs_reboot("ardupilot", "VISO_TYPE") and needs_reboot("ardupilot", "GPS1_TYPE")
    assert needs_reboot("ardupilot", "MAV3_EXTRA1") and needs_reboot("ardupilot", "SR2_EXTRA1")
    assert not needs_reboot("ardupilot", "EK3_SRC1_POSXY")
    assert not needs_reboot("ardupilot", "ARMING_SKIPCHK")
    assert needs_reboot("px4", "EKF2_EV_DELAY") and needs_reboot("px4", "MAV_1_MODE")


def test_delays_follow_how_each_autopilot_uses_our_stamps():
    rng = np.random.default_rng(3)
    samples = list(0.030 + rng.exponential(0.008, 300))
    windows = [min(samples[i:i + 100]) for i in (0, 100, 200)]
    ms, basis = ardupilot_delay_ms(samples, [0.004, 0.006, 0.005], "measured")
    assert ms == pytest.approx(np.median(windows) * 1e3 + 2.5)
    assert "half the TIMESYNC round trip 2.5 ms" in basis
    ms, basis = px4_delay_ms(samples, [0.004], "measured")
    assert ms == 0.0 and "maps our capture stamps" in basis
    ms, basis = px4_delay_ms(samples, [0.030], "measured")
    assert ms == pytest.approx(np.median(samples) * 1e3 + 15)
    assert "over PX4's 10 ms" in basis


def test_capture_to_send_is_measured_on_the_running_service():
    cfg = replace(Config(), camera={"source": "testpattern", "width": 64, "height": 48},
                  mounting={"preset": "forward"})
    source = TestPatternSource(64, 48, 30.0)
    samples = measure_capture_to_send(cfg, 1.5, source, lambda frame: FakeTracker())
    assert len(samples) >= 5
    assert all(0 < s < 0.2 for s in samples)  # stale estimates (> max_latency_s) are not sent


def statuses(flavour: str, rates: dict[str, float]) -> list[StreamStatus]:
    return [StreamStatus(n, Answer.ACCEPTED, rate_hz=rates.get(n.kind, 0.0))
            for n in needs_for(flavour)]


def probe(rates: dict[str, float], params: dict, unasked=None, **kw) -> Probe:
    flavour = kw.pop("flavour", "ardupilot")
    unasked = unasked if unasked is not None else {n.kind: 0.0 for n in needs_for(flavour)}
    fields = {"flavour": flavour, "system_id": 1, "link": "tcp:x:1", "usb": False, "baud": 0,
              "params": params, "params_complete": True, "mavlink1": False,
              "unasked": unasked, "streams": statuses(flavour, rates), "rtt_s": [],
              "gps_fix_type": None, "prearm": []}
    return Probe(**(fields | kw))


ALL = {"attitude": 50, "IMU": 50, "barometer": 10, "downward rangefinder": 20}
PORTS = {"MAV1_EXTRA1": 0, "MAV2_EXTRA1": 4, "MAV3_EXTRA1": 0, "SERIAL0_PROTOCOL": 2,
         "SERIAL1_PROTOCOL": 2, "SERIAL2_PROTOCOL": 2}


def test_missing_attitude_names_the_port_by_what_was_heard():
    """MAV2 streams EXTRA1 at 4 Hz (the GCS port); nothing was heard unasked here: MAV3."""
    found = by_name(probe_findings(probe({**ALL, "attitude": 0}, PORTS), CTX))
    f = found["MAV3_EXTRA1"]
    assert (f.severity, f.value, f.set_to) == (Severity.ERROR, 0, 50)
    assert "never publishes" in f.message
    both = by_name(probe_findings(probe({**ALL, "attitude": 0}, {**PORTS, "MAV2_EXTRA1": 0}), CTX))
    assert "MAV2_EXTRA1 = 50" in both["ATTITUDE"].message
    assert "MAV3_EXTRA1 = 50" in both["ATTITUDE"].message


def test_scale_sources_and_optional_streams():
    found = by_name(probe_findings(probe({"attitude": 50}, PORTS), CTX))
    assert found["scale"].severity == Severity.ERROR
    assert found["DISTANCE_SENSOR"].severity == Severity.NOTE
    assert found["LOCAL_POSITION_NED"].severity == Severity.NOTE
    imu_only = by_name(probe_findings(probe({**ALL, "barometer": 0}, PORTS), CTX))
    assert imu_only["SCALED_PRESSURE"].severity == Severity.WARNING
    assert "MAV3_RAW_SENS = 10" in imu_only["SCALED_PRESSURE"].message
    instances = {"MAV_0_MODE": 0, "MAV_0_CONFIG": 101, "MAV_1_MODE": 0, "MAV_1_CONFIG": 0}
    px4 = by_name(probe_findings(probe({**ALL, "IMU": 0}, instances, flavour="px4"), CTX))
    assert (px4["MAV_0_MODE"].set_to, px4["MAV_0_MODE"].severity) == (2, Severity.WARNING)


def test_mavlink1_and_prearm_texts():
    v1_port = {**PORTS, "SERIAL2_PROTOCOL": 1}
    found = by_name(probe_findings(probe(ALL, v1_port, mavlink1=True), CTX))
    assert (found["SERIAL2_PROTOCOL"].set_to, found["SERIAL2_PROTOCOL"].severity) == (
        2, Severity.ERROR)
    texts = ["PreArm: VisOdom: not healthy", "PreArm: Need Position Estimate",
             "PreArm: Battery 1 below minimum arming voltage"]
    findings = [f for f in probe_findings(probe(ALL, PORTS, prearm=texts), CTX)
                if f.name == "pre-arm"]
    assert [f.severity for f in findings] == [Severity.NOTE, Severity.NOTE, Severity.ERROR]
    assert "Battery 1" in findings[2].message


class EchoAutopilot:
    """An in-process ArduPilot parameter server that drops two answers of the list."""

    def __init__(self, client_box: list, values: dict[str, float]):
        self.box = client_box
        self.values = values
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink2.MAVLink(None)
        self.dropped = {1, 3}

    def send(self, msg) -> bool:
        names = list(self.values)
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            replies = [i for i in range(len(names)) if i not in self.dropped]
        elif kind == "PARAM_REQUEST_READ":
            replies = [msg.param_index]
        else:  # PARAM_SET: ArduPilot keeps integers of an INT8 parameter
            self.values[msg.param_id] = float(round(msg.param_value))
            replies = [names.index(msg.param_id)]
        for i in replies:
            reply = self.mav.param_value_encode(names[i].encode(), self.values[names[i]],
                                                mavlink2.MAV_PARAM_TYPE_INT8, len(names), i)
            parsed = self.parser.parse_buffer(reply.pack(self.mav))[0]
            asyncio.get_running_loop().call_soon(self.box[0].on_message, parsed)
        return True


def test_param_client_reads_the_whole_list_and_sets_with_read_back():
    values = {f"P{i}": float(i) for i in range(6)}

    async def scenario():
        box = []
        codec = EchoAutopilot(box, values)
        codec.mav_out = mavlink2.MAVLink(None, srcSystem=255, srcComponent=197)
        client = ParamClient(type("C", (), {"mav": codec.mav_out, "send": codec.send})(),
                             lambda: (1, 1), lambda: "ardupilot")
        box.append(client)
        got = await client.fetch_all(5.0)
        held = await client.set("P2", 7)
        rounded = await client.set("P3", 2.5)  # the autopilot keeps 2
        return got, held, rounded, client.complete

    got, held, rounded, complete = asyncio.run(scenario())
    assert got == {f"P{i}": float(i) for i in range(6)} and complete
    assert held == 7 and values["P2"] == 7
    assert rounded == 2
    assert wire_value("ardupilot", 2, mavlink2.MAV_PARAM_TYPE_INT8) == 2.0


@pytest.mark.parametrize(("baud", "output", "usb", "severity"), [
    (57600, "odometry", False, Severity.ERROR), (115200, "odometry", False, None),
    (115200, "both", False, Severity.ERROR), (921600, "both", False, None),
    (57600, "odometry", True, None)])
def test_a_serial_link_must_carry_the_vision_and_the_streams(baud, output, usb, severity):
    """ODOMETRY is 245 bytes a frame: 30 a second do not fit in 57600 baud (5760 bytes/s)."""
    ctx = CheckContext(output=output, vision_rate_hz=30, delay_ms=35, gps_present=False)
    found = by_name(probe_findings(probe(ALL, PORTS, baud=baud, usb=usb), ctx))
    if severity is None:
        assert "baud rate" not in found
    else:
        assert found["baud rate"].severity == severity
        assert "SERIALn_BAUD 921" in found["baud rate"].message
