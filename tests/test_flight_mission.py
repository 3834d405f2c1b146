"""Mission files for `sdvl fly`: the built-in ones, the format's two spellings, and one clear
error naming the step and key for each kind of mistake."""

from __future__ import annotations

import pytest

from sdvl.cli import main
from sdvl.errors import InputError
from sim.flight.mission import Action, WaitFor, load_mission, parse_mission


def test_default_mission_is_the_first_vision_flight():
    mission = load_mission("default")
    actions = [s.action for s in mission.steps]
    assert actions[:4] == [Action.WAIT, Action.WAIT, Action.MODE, Action.ARM]
    takeoff = mission.steps[actions.index(Action.TAKEOFF)]
    hold = mission.steps[actions.index(Action.HOLD)]
    assert takeoff.value == 3.0 and hold.value == 30.0
    assert mission.steps[actions.index(Action.HOLD) - 1].value == "LOITER"
    corners = [s.value[:2] for s in mission.steps if s.action is Action.GOTO]
    assert corners == [(2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)]
    assert actions[-1] is Action.LAND
    assert mission.planned_path() == [(0, 0, 0), (0, 0, -3), (2, 0, -3), (2, 2, -3), (0, 2, -3),
                                      (0, 0, -3), (0, 0, 0)]


def test_survey_mission_flies_a_larger_square_over_the_survey_world():
    mission = load_mission("survey")
    assert mission.world == "survey-down"
    corners = [s.value for s in mission.steps if s.action is Action.GOTO]
    assert max(abs(v) for c in corners for v in c[:2]) == 10.0


def test_table_form_and_inline_form_read_the_same():
    inline = parse_mission({"steps": [{"wait": "extnav", "timeout_s": 5},
                                      {"goto": [1, 2, 4], "tolerance_m": 0.2}]})
    tables = parse_mission({"steps": [dict(wait="extnav", timeout_s=5.0),
                                      dict(goto=[1.0, 2.0, 4.0], tolerance_m=0.2)]})
    assert inline.steps == tables.steps
    assert inline.steps[0].value is WaitFor.EXTNAV and inline.steps[0].timeout_s == 5.0
    assert inline.steps[1].value == (1.0, 2.0, 4.0) and inline.steps[1].tolerance_m == 0.2


def test_mode_names_are_arducopter_modes_in_any_case():
    assert parse_mission({"steps": [{"mode": "loiter"}]}).steps[0].value == "LOITER"


@pytest.mark.parametrize(("steps", "words"), [
    ([{"arm": True, "takeoff": 3}], "step 1 needs exactly one action key"),
    ([{"hold": 5}, {"mode": "HOVER"}], "step 2.mode: 'HOVER' is not an ArduCopter mode"),
    ([{"goto": [1]}], "step 1.goto must be [north, east]"),
    ([{"goto": [1, 2, -3]}], "the height must be above the ground"),
    ([{"hold": 5, "timeout_s": 9}], "a hold has no timeout_s"),
    ([{"takeoff": -1}], "step 1.takeoff must be more than 0"),
    ([{"wait": "gps"}], "'gps' is not one of autopilot, vision, position, extnav"),
    ([{"land": True, "timout_s": 3}], "unknown key 'timout_s': did you mean 'timeout_s'?"),
    ([{"arm": "yes"}], "step 1.arm must be true"),
])
def test_mistakes_name_the_step_and_key(steps, words):
    with pytest.raises(InputError, match=None) as caught:
        parse_mission({"steps": steps}, "m.toml")
    assert words in str(caught.value) and str(caught.value).startswith("m.toml: ")


def test_a_mission_needs_steps_and_a_known_world():
    with pytest.raises(InputError, match="steps must be a list"):
        parse_mission({"world": "hover-down"})
    with pytest.raises(InputError, match="world 'moon' is not a synthetic preset"):
        parse_mission({"world": "moon", "steps": [{"arm": True}]})


def test_bad_mission_file_is_one_line_and_exit_2(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text('steps = [ { arm = true }, { hover = 3 } ]\n')
    assert main(["fly", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml: step 2 needs exactly one action key" in err[0]
    assert main(["fly", "nosuchmission"]) == 2
    assert "no mission 'nosuchmission'" in capsys.readouterr().err


def test_frames_csv_is_for_one_virtual_clock_flight(tmp_path, capsys):
    out = str(tmp_path / "f.csv")
    assert main(["fly", "--seeds", "0-1", "--frames-csv", out]) == 2
    assert "--frames-csv writes one virtual-clock flight" in capsys.readouterr().err
    assert main(["fly", "--realtime", "--frames-csv", out]) == 2
    assert not (tmp_path / "f.csv").exists()


def test_vibration_spread_is_for_the_virtual_clock_loop_and_a_share(capsys):
    for args in (["--vibration-spread", "0.5"], ["--vibration-spread", "-0.1"],
                 ["--vibration-spread", "0.03", "--realtime"]):
        assert main(["fly", *args]) == 2
        assert "--vibration-spread is the virtual-clock loop's IMU" in capsys.readouterr().err


def test_drop_frames_is_for_the_virtual_clock_loop_and_a_share(capsys):
    for args in (["--drop-frames", "0.7"], ["--drop-frames", "-0.1"],
                 ["--drop-frames", "0.2", "--realtime"]):
        assert main(["fly", *args]) == 2
        assert "--drop-frames is the virtual-clock loop's share" in capsys.readouterr().err
