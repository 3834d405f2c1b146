"""The service config: schema, example file, and one-line errors with exit code 2."""

from __future__ import annotations

import dataclasses
import re
import tomllib

import pytest

from daemon.config import (
    EXAMPLE_CONFIG,
    SECTIONS,
    Config,
    config_from_dict,
    load_config,
    replace,
)
from sdvl.cli import main
from sdvl.errors import InputError


def test_example_config_documents_every_key_with_its_default():
    data = tomllib.loads(EXAMPLE_CONFIG.read_text())
    assert load_config(EXAMPLE_CONFIG) == Config()
    text = EXAMPLE_CONFIG.read_text()
    for name, cls in SECTIONS.items():
        assert set(data[name]) == {f.name for f in dataclasses.fields(cls)}, name
        for f in dataclasses.fields(cls):
            # each key has a comment line above it or above its group
            block = text.split(f"[{name}]")[1].split(f"\n{f.name} =")[0]
            assert "#" in block, f"{name}.{f.name} undocumented"
    assert "tracker" in data


@pytest.mark.parametrize(("data", "message"), [
    ({"mavlink": {"lnk": "udpout:x:1"}}, "unknown key 'mavlink.lnk': did you mean 'link'?"),
    ({"camra": {}}, "unknown section '[camra]': did you mean 'camera'?"),
    ({"mavlink": {"max_rate_hz": "fast"}}, "mavlink.max_rate_hz must be a number, got 'fast'"),
    ({"mavlink": {"system_id": 1.5}}, "mavlink.system_id must be an integer"),
    ({"camera": {"realtime": 1}}, "camera.realtime must be true or false"),
    ({"mavlink": {"max_rate_hz": 80}}, "mavlink.max_rate_hz must be in (0, 50]"),
    ({"mavlink": {"output": "vpe"}}, "mavlink.output must be one of"),
    ({"mounting": {"pitch_deg": -90}}, "used only with mounting.preset = \"custom\""),
    ({"mounting": {"scale": 0}}, "mounting.scale must be in (0, 1e+06]"),
    ({"origin": {"latitude_deg": 91.0}}, "origin.latitude_deg must be -90..90"),
    ({"mavlink": 3}, "[mavlink] must be a table"),
    ({"camera": {"width": -64, "height": 48}}, "camera.width must be 0..8192"),
    ({"camera": {"width": 640}}, "camera.width and camera.height are set together"),
    ({"camera": {"reconnect_min_s": 9.0}}, "camera.reconnect_min_s must be <="),
    ({"mavlink": {"link": "serial:/dev/ttyAMA0:0"}}, "a serial port needs its baud rate"),
    ({"mavlink": {"link": "/dev/ttyACM0:115000"}}, "115000 is not a serial baud rate"),
    ({"mavlink": {"autopilot_system_id": 256}}, "mavlink.autopilot_system_id must be 0..255"),
    ({"service": {"log_level": "loud"}}, "service.log_level must be one of debug, info"),
])
def test_bad_config_names_the_key_and_the_fix(data, message):
    with pytest.raises(InputError) as err:
        config_from_dict(data)
    assert message in str(err.value)


@pytest.mark.parametrize(("line", "message"), [
    ("[origin]\naltitude_m = nan", "origin.altitude_m must be a finite number, got nan"),
    ("[origin]\naltitude_m = 1e300", "origin.altitude_m must be -1000..10000"),
    ("[mounting]\nscale = inf", "mounting.scale must be a finite number, got inf"),
    ("[fusion]\nbaro_std_m = -inf", "fusion.baro_std_m must be a finite number"),
])
def test_values_from_a_file_must_be_finite_and_in_range(tmp_path, line, message):
    path = tmp_path / "sdvl.toml"
    path.write_text(line + "\n")
    with pytest.raises(InputError) as err:
        load_config(path)
    assert message in str(err.value) and str(path) in str(err.value)


def test_tracker_numbers_must_be_finite():
    from vo.config import TrackerConfig

    with pytest.raises(InputError, match=r"tracker\.ransac_threshold_px must be a finite number"):
        TrackerConfig.from_dict({"ransac_threshold_px": float("nan")})


def test_programmatic_copies_are_checked_too():
    with pytest.raises(InputError, match=r"mavlink\.max_latency_s must be in"):
        replace(Config(), mavlink={"max_latency_s": 1e6})


def test_numbers_accept_integers_and_custom_mounting_accepts_angles():
    cfg = config_from_dict({"mavlink": {"max_rate_hz": 30},
                            "mounting": {"preset": "custom", "pitch_deg": -45}})
    assert cfg.mavlink.max_rate_hz == 30.0 and isinstance(cfg.mavlink.max_rate_hz, float)
    assert cfg.mounting.pitch_deg == -45.0


def test_sdvl_run_bad_config_is_one_line_and_exit_2(tmp_path, capsys):
    path = tmp_path / "sdvl.toml"
    path.write_text("[mavlink]\nlink = \"udpout:127.0.0.1:14550\"\nheartbeat_timeout = 3\n")
    assert main(["run", "--config", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert re.search(r"unknown key 'mavlink.heartbeat_timeout': did you mean "
                     r"'heartbeat_timeout_s'\?", err)
    assert str(path) in err


def test_sdvl_run_invalid_toml_and_missing_file(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[mavlink\n")
    assert main(["run", "--config", str(path)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    assert main(["run", "--config", str(tmp_path / "none.toml")]) == 2
    assert "config file not found" in capsys.readouterr().err


def test_bad_tracker_key_is_reported_at_start(tmp_path, capsys):
    path = tmp_path / "sdvl.toml"
    path.write_text("[camera]\nsource = \"testpattern\"\n[tracker]\nno_such_option = 1\n")
    assert main(["run", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "no_such_option" in err and len(err.strip().splitlines()) == 1


def test_missing_calibration_for_a_device(tmp_path, capsys):
    path = tmp_path / "sdvl.toml"
    path.write_text("[camera]\nsource = \"/dev/video42\"\n")
    assert main(["run", "--config", str(path)]) == 2
    assert "camera.calibration: set the path of a camera.yaml" in capsys.readouterr().err
