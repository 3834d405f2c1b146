"""`sdvl check-autopilot` against simulated ArduPilot and PX4 autopilots."""

from __future__ import annotations

import socket

import pytest

from daemon.autopilot_params import check_parameters, from_wire, parameter_names, wire_value
from sdvl.cli import main
from sim.autopilot import SimAutopilot, configured_options
from sim.autopilot.params import INT32, configured_values, px4_specs


def check(sim: SimAutopilot, capsys, *extra: str) -> tuple[int, str]:
    code = main(["check-autopilot", "--link", sim.url, "--timeout", "4", *extra])
    return code, capsys.readouterr().out


def test_vision_ready_ardupilot_passes(capsys):
    with SimAutopilot(configured_options(heartbeat_hz=5, viso_type=3)) as sim:
        code, out = check(sim, capsys)
    assert code == 0, out
    assert "autopilot: ardupilot (system 1)" in out
    assert "VISO_TYPE          3" in out and "OK: the autopilot is set up for vision" in out
    reads = [r.msg for r in sim.messages("PARAM_REQUEST_READ")]
    assert {m.param_id for m in reads} == set(parameter_names("ardupilot"))
    assert all((m.target_system, m.target_component, m.param_index) == (1, 1, -1) for m in reads)
    assert all(r.msg.get_srcComponent() == 197 for r in sim.received)


def test_misconfigured_ardupilot_says_what_to_set(capsys):
    bad = {"VISO_TYPE": 0, "EK3_SRC1_POSXY": 3, "VISO_SCALE": 2.0, "AHRS_EKF_TYPE": 2,
           "VISO_DELAY_MS": 10}
    with SimAutopilot(configured_options(port="tcp", heartbeat_hz=5, param_overrides=bad)) as sim:
        code, out = check(sim, capsys, "--latency-ms", "62")
    assert code == 1
    assert "ERROR   VISO_TYPE = 0: set 3" in out
    assert "ERROR   EK3_SRC1_POSXY = 3: set 6 (ExternalNav)" in out
    assert "ERROR   AHRS_EKF_TYPE = 2: set 3" in out
    assert "WARNING VISO_SCALE = 2: set 1" in out
    assert "WARNING VISO_DELAY_MS = 10: set 62" in out


def test_px4_int_parameters_are_decoded(capsys):
    with SimAutopilot(configured_options(flavour="px4", port="pty", heartbeat_hz=5,
                                 param_overrides={"EKF2_EV_CTRL": 0, "EKF2_HGT_REF": 3})) as sim:
        code, out = check(sim, capsys)
    assert code == 1
    assert "autopilot: px4" in out
    assert "EKF2_HGT_REF       3" in out  # an INT32 sent as its bytes, decoded
    assert "ERROR   EKF2_EV_CTRL = 0: set 15" in out


def test_mavlink1_link_is_reported(capsys):
    with SimAutopilot(configured_options(mavlink1=True, heartbeat_hz=5)) as sim:
        code, out = check(sim, capsys)
    assert code == 1 and "link speaks MAVLink 1" in out


def test_no_autopilot_is_one_line_exit_2(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as quiet:
        quiet.bind(("127.0.0.1", 0))
        port = quiet.getsockname()[1]
        code = main(["check-autopilot", "--link", f"udpout:127.0.0.1:{port}", "--timeout", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "no autopilot heartbeat on udpout:127.0.0.1:" in err


@pytest.mark.parametrize("value", [0, 1, 11, 15, -1, 123456])
def test_px4_int32_wire_encoding_round_trips(value):
    assert from_wire("px4", wire_value("px4", value, INT32), INT32) == value
    assert from_wire("ardupilot", wire_value("ardupilot", value, INT32), INT32) == value


def test_rules_depend_on_the_message_type():
    ardupilot = {name: 0.0 for name in ("VISO_QUAL_MIN",)}
    findings = check_parameters("ardupilot", {**ardupilot, "VISO_QUAL_MIN": 10},
                                "vision_position")
    assert any(f.name == "VISO_QUAL_MIN" and "no quality" in f.fix for f in findings)
    px4 = {name: spec.default for name, spec in px4_specs().items()}
    px4.update({**configured_values("px4"), "EKF2_EV_CTRL": 11, "EKF2_HGT_REF": 3})
    assert check_parameters("px4", px4, "odometry") == []
    findings = check_parameters("px4", {**px4, "EKF2_EV_CTRL": 15}, "vision_position")
    assert [f.severity for f in findings] == ["warning"]
