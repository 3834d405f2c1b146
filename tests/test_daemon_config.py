"""The service config: schema, example file, and one-line errors with exit code 2."""

from __future__ import annotations

import dataclasses
import re
import tomllib

import pytest

from daemon.config import EXAMPLE_CONFIG, SECTIONS, Config, config_from_dict, load_config
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
    ({"mounting": {"scale": 0}}, "mounting.scale must be > 0"),
    ({"origin": {"latitude_deg": 91.0}}, "origin.latitude_deg must be -90..90"),
    ({"mavlink": 3}, "[mavlink] must be a table"),
])
def test_bad_config_names_the_key_and_the_fix(data, message):
    with pytest.raises(InputError) as err:
        config_from_dict(data)
    assert message in str(err.value)


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
