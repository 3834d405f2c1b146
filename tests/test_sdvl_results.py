"""`sdvl results`: sections are found, rerun and replaced; prose around them is kept."""

from __future__ import annotations

import pytest

from sdvl.cli import main
from sdvl.errors import InputError
from sdvl.results import sections

DOC = """# Results
Intro kept.

<!-- section: answer -->
Command: `python -c "print('forty two')"`
Measured: long ago
```text
41
```
<!-- end: answer -->
Comment kept.

<!-- section: other -->
Command: `python -c "print(1)"`
<!-- end: other -->
"""


def test_sections_are_listed_with_their_commands():
    found = sections(DOC)
    assert [s.name for s in found] == ["answer", "other"]
    assert found[0].command == "python -c \"print('forty two')\""


def test_a_named_section_is_rerun_and_the_rest_kept(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text(DOC)
    assert main(["results", "--file", str(path), "answer"]) == 0
    text = path.read_text()
    assert "forty two" in text and "\n41\n" not in text and "long ago" not in text
    assert "Intro kept." in text and "Comment kept." in text
    assert text.count("<!-- section: ") == 2 and 'print(1)"`\n<!-- end: other' in text


def test_unknown_section_and_missing_command_are_user_errors(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text(DOC)
    assert main(["results", "--file", str(path), "nope"]) == 2
    with pytest.raises(InputError, match="no line 'Command"):
        sections("<!-- section: x -->\nno command\n<!-- end: x -->\n")


def test_the_projects_results_file_parses():
    from sdvl.results import RESULTS_FILE

    assert sections(RESULTS_FILE.read_text()), f"{RESULTS_FILE} has no sections"
