"""A first flight as a new user makes it (issue 26): the autopilot set up by `sdvl check-autopilot
--apply --reboot` and nothing else, the service replaying a synthetic flight in real time
against it from power-on. The simulated autopilot behaves like the real one
(sim/autopilot/BEHAVIOUR.md): no streams unless asked, the VisOdom pre-arm check, EKF3's height
reset to our z when it starts using external nav, VISO_TYPE 2's ignored second after a
reset_counter change. What is asserted holds on a loaded machine (frames dropped do not matter)."""

from __future__ import annotations

import pytest

from daemon.config import Config, replace
from sdvl.cli import main
from sim.autopilot import SimAutopilot, SimOptions, configured_options
from sim.replay.harness import run_replay
from sim.replay.report import build_report
from sim.synth.flight import synthetic_sequence

FLIGHT_FRAMES = 60  # 2 s of flight after the 5 s pre-flight on the ground


pytestmark = pytest.mark.usefixtures("quick_autopilot_probe")


def applied(options: SimOptions, capsys) -> SimOptions:
    """The autopilot's stored parameters after `check-autopilot --apply --reboot` said OK."""
    with SimAutopilot(options) as autopilot:
        code = main(["check-autopilot", "--link", autopilot.url, "--timeout", "4",
                     "--latency-ms", "35", "--apply", "--reboot"])
        out = capsys.readouterr().out
        assert code == 0, out
        stored = dict(autopilot.model.params.saved)
    return SimOptions(flavour=options.flavour, params=stored)


def first_flight(preset: str, options: SimOptions) -> dict:
    sequence = synthetic_sequence(preset, frames=FLIGHT_FRAMES, size=(320, 240), seed=0)
    config = replace(Config(), fusion={"enabled": True})
    run = run_replay(sequence, config, realtime=True, progress=False, autopilot=options)
    return build_report(run, None)[0]


@pytest.mark.parametrize(("flavour", "preset"), [("ardupilot", "hover-down"),
                                                  ("px4", "survey-down")])
def test_after_check_autopilot_apply_it_arms_and_uses_our_estimate_without_a_step(
        flavour, preset, capsys):
    """ArduPilot from its firmware defaults; PX4 from a companion port already configured (a
    fresh PX4 has no MAVLink there: check-autopilot says which MAV_n_CONFIG to set)."""
    start = (SimOptions(port="tcp", reboot_downtime_s=2.0) if flavour == "ardupilot"
             else configured_options("px4", port="tcp", reboot_downtime_s=2.0))
    r = first_flight(preset, applied(start, capsys))
    assert r["armed_s"] is not None and r["armed_s"] < 0, r["prearm_failures"]  # on the ground
    assert r["extnav_s"] is not None and r["extnav_s"] < 0  # before take-off
    assert r["first_reset_counter"] == 0
    assert r["extnav_height_step_m"] < 0.1
    assert not r["failsafes"]
