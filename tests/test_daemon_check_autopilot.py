"""`sdvl check-autopilot` against simulated ArduPilot and PX4 autopilots, and its rules."""

from __future__ import annotations

import socket

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from daemon.autopilot_params import CheckContext, Finding, Severity, from_wire, wire_value
from sdvl.cli import main
from sim.autopilot import Release, SimAutopilot, SimOptions, configured_options
from sim.autopilot.params import INT32

pytestmark = pytest.mark.usefixtures("quick_autopilot_probe")


def check(sim: SimAutopilot, capsys, *extra: str) -> tuple[int, list[str]]:
    code = main(["check-autopilot", "--link", sim.url, "--timeout", "4", *extra])
    return code, capsys.readouterr().out.splitlines()


def test_ready_ardupilot_is_ok_and_everything_was_read_and_asked_for(capsys):
    with SimAutopilot(configured_options(heartbeat_hz=5, streams={})) as sim:
        code, out = check(sim, capsys, "--measure-s", "0")  # the delay's rule: its own test
    assert code == 0, out
    assert out[0].startswith("OK: a flight on vision would work (ardupilot, system 1 on ")
    assert not any(line.startswith(("ERROR", "WARNING")) for line in out)
    assert sim.messages("PARAM_REQUEST_LIST")  # the names it has, not an assumed version
    intervals = [(int(r.msg.param1), r.msg.param2) for r in sim.messages("COMMAND_LONG")
                 if r.msg.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL]
    assert (mavlink2.MAVLINK_MSG_ID_ATTITUDE, 20000) in intervals  # asked as the service asks
    assert (mavlink2.MAVLINK_MSG_ID_ATTITUDE, 0) in intervals  # and put back to the default
    assert sim.messages("TIMESYNC")  # round trips timed
    assert all(r.msg.get_srcComponent() == 197 for r in sim.received)


def test_misconfigured_ardupilot_lists_every_setting_first_the_verdict(capsys):
    bad = {"VISO_TYPE": 0, "EK3_SRC1_POSXY": 3, "EK3_SRC1_YAW": 6, "VISO_SCALE": 2.0,
           "AHRS_EKF_TYPE": 2, "VISO_ORIENT": 25, "VISO_DELAY_MS": 10}
    with SimAutopilot(configured_options(port="tcp", heartbeat_hz=5,
                                         param_overrides=bad)) as sim:
        code, out = check(sim, capsys, "--latency-ms", "62")
    assert code == 1
    assert out[0].startswith("NOT READY: 6 problems would stop a flight on vision (ardupilot")
    for line in ("ERROR   VISO_TYPE = 0: set 2: ArduPilot ignores vision messages",
                 "ERROR   EK3_SRC1_POSXY = 3: set 6: 6 (ExternalNav)",
                 "ERROR   EK3_SRC1_YAW = 6: set 1: 1 (Compass): the service takes its north",
                 "ERROR   AHRS_EKF_TYPE = 2: set 3",
                 "ERROR   VISO_ORIENT = 25: set 0",
                 "ERROR   VISO_SCALE = 2: set 1",
                 "WARNING VISO_DELAY_MS = 10: set "):
        assert any(o.startswith(line) for o in out), line
    delay = next(o for o in out if o.startswith("WARNING VISO_DELAY_MS"))
    assert "(capture-to-send 62 ms (given with --latency-ms) + half the TIMESYNC" in delay
    assert out[-1].startswith("`sdvl check-autopilot --apply` sets ")


def test_px4_int_parameters_are_decoded_and_yaw_fusion_refused(capsys):
    with SimAutopilot(configured_options(flavour="px4", port="pty", heartbeat_hz=5,
                                         params={"EKF2_EV_CTRL": 15})) as sim:
        code, out = check(sim, capsys, "--measure-s", "0")
    assert code == 1
    assert out[0].startswith("NOT READY: 1 problem would stop a flight on vision (px4")
    assert any(o.startswith("ERROR   EKF2_EV_CTRL = 15: set 7: bit 3 (yaw) would feed PX4 its "
                            "own heading back") for o in out)
    assert any(o.startswith("NOTE    EKF2_EV_DELAY = 0: not checked") for o in out)


def test_mavlink1_port_is_not_ready(capsys):
    with SimAutopilot(configured_options(mavlink1=True, heartbeat_hz=5)) as sim:
        code, out = check(sim, capsys, "--latency-ms", "40")
    assert code == 1
    assert any("still sends MAVLink 1 after hearing MAVLink 2" in o for o in out)


@pytest.mark.parametrize("release", [Release.MASTER_2025, Release.COPTER_4_5])
def test_fresh_ardupilot_lists_every_setting_and_apply_reboot_makes_it_ok(capsys, release):
    """A fresh ArduCopter of either parameter generation: NOT READY with every setting; after
    --apply --reboot the same check says OK."""
    with SimAutopilot(SimOptions(port="tcp", release=release, reboot_downtime_s=2.0)) as sim:
        code, out = check(sim, capsys, "--latency-ms", "35", "--apply", "--reboot")
    assert code == 0, out
    first = out.index("after the reboot:")
    assert out[0].startswith("NOT READY: 4 problems")
    for name, value in (("VISO_TYPE", 2), ("EK3_SRC1_POSXY", 6), ("EK3_SRC1_VELXY", 6),
                        ("EK3_SRC1_VELZ", 6), ("VISO_POS_M_NSE", 0.1)):
        assert f"set {name} = {value:g}, read back {value:g}" in out[:first]
        assert sim.params.get(name) == pytest.approx(value)
    # 35 ms capture-to-send + half the round trip, which a loaded machine lengthens
    delay = next(int(o.split()[3].rstrip(",")) for o in out if o.startswith("set VISO_DELAY_MS"))
    assert 35 <= delay <= 60 and sim.params.get("VISO_DELAY_MS") == delay
    gps = "GPS1_TYPE" if release is Release.MASTER_2025 else "GPS_TYPE"
    assert any(line.startswith(f"NOTE    {gps} = 1: could not tell") for line in out)
    assert out[first + 1].startswith("OK: a flight on vision would work (ardupilot")
    assert sim.messages("COMMAND_LONG") and any(
        r.msg.command == mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and r.msg.param1 == 1
        for r in sim.messages("COMMAND_LONG"))


def test_px4_apply_and_reboot(capsys):
    with SimAutopilot(configured_options(flavour="px4", port="tcp", reboot_downtime_s=2.0,
                                         params={"EKF2_EV_CTRL": 15})) as sim:
        code, out = check(sim, capsys, "--latency-ms", "35", "--apply", "--reboot")
    assert code == 0, out
    assert "set EKF2_EV_CTRL = 7, read back 7" in out
    assert sim.params.get("EKF2_EV_CTRL") == 7


def test_fresh_px4_companion_port_is_silent_exit_3(capsys):
    with SimAutopilot(SimOptions(flavour="px4")) as sim:
        code = main(["check-autopilot", "--link", sim.url, "--timeout", "2"])
    err = capsys.readouterr().err
    assert code == 3 and "MAV_n_CONFIG" in err


def test_no_autopilot_is_one_line_and_exit_3(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as quiet:
        quiet.bind(("127.0.0.1", 0))
        port = quiet.getsockname()[1]
        code = main(["check-autopilot", "--link", f"udpout:127.0.0.1:{port}", "--timeout", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 3 and len(err.splitlines()) == 1
    assert "no autopilot heartbeat on udpout:127.0.0.1:" in err and "udpin:" in err


def test_a_port_that_cannot_be_opened_is_named_in_one_line(capsys):
    code = main(["check-autopilot", "--link", "/dev/ttySDVL-missing,921600", "--timeout", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 3 and len(err.splitlines()) == 1
    assert err.startswith("sdvl check-autopilot: cannot open serial:/dev/ttySDVL-missing:921600")
    assert "is sdvl-companion running?" in err


def test_bad_arguments_exit_2(capsys):
    assert main(["check-autopilot", "--link", "udp:nowhere"]) == 2
    assert "accepted forms" in capsys.readouterr().err
    assert main(["check-autopilot", "--link", "udpin:0.0.0.0:14550", "--reboot"]) == 2


@pytest.mark.parametrize("value", [0, 1, 7, 15, -1, 123456])
def test_px4_int32_wire_encoding_round_trips(value):
    assert from_wire("px4", wire_value("px4", value, INT32), INT32) == value
    assert from_wire("ardupilot", wire_value("ardupilot", value, INT32), INT32) == value


def test_finding_lines_say_value_what_to_set_and_why():
    assert str(Finding(Severity.ERROR, "VISO_TYPE", 0, "why", 2)) == \
        "ERROR   VISO_TYPE = 0: set 2: why"
    assert str(Finding(Severity.ERROR, "VISO_TYPE", None, "no VisualOdom")) == \
        "ERROR   VISO_TYPE (not on this autopilot): no VisualOdom"
    assert str(Finding(Severity.NOTE, "streams", None, "heard", is_param=False)) == \
        "NOTE    streams: heard"
    assert CheckContext().good_std_m == 0.05
