"""The `sdvl` command: every subcommand has --help; usage errors exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sdvl.cli import COMMANDS, main


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    assert COMMANDS[command][1].split()[0] in capsys.readouterr().out


def test_no_command_prints_help_and_exits_2(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_unknown_command_exits_2():
    with pytest.raises(SystemExit) as info:
        main(["fly-to-the-moon"])
    assert info.value.code == 2


def test_installed_entry_point_runs():
    result = subprocess.run([sys.executable, "-m", "sdvl.cli", "--help"], capture_output=True,
                            text=True, check=False)
    assert result.returncode == 0 and "eval" in result.stdout
