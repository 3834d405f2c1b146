"""`sdvl results [NAME ...]`: regenerate the measurements in RESULTS.md.

Measurements live in RESULTS.md, not in code comments. Each section there holds the command that
produced it and that command's output:

    <!-- section: NAME -->
    Command: `sdvl track-table vamr_ex01_checkerboard736`
    Measured: 2026-11-26 (2 cores, load 1.2)
    ```text
    ...output...
    ```
    <!-- end: NAME -->

Prose about a section goes outside its markers and is kept. This command reruns the named
sections' commands (all with --all) and replaces their output and the Measured line.
"""

from __future__ import annotations

import argparse
import datetime
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from sdvl.errors import InputError, read_text

RESULTS_FILE = Path(__file__).resolve().parents[1] / "RESULTS.md"
SECTION = re.compile(r"<!-- section: (?P<name>[\w.-]+) -->\n(?P<body>.*?)<!-- end: (?P=name) -->\n",
                     re.DOTALL)
COMMAND = re.compile(r"^Command: `(?P<command>[^`]+)`$", re.MULTILINE)


@dataclass(frozen=True)
class Section:
    """One regenerable section of the results file."""

    name: str
    command: str


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sdvl results`."""
    parser.add_argument("names", nargs="*", metavar="NAME", help="sections to regenerate")
    parser.add_argument("--all", action="store_true", help="regenerate every section")
    parser.add_argument("--list", action="store_true", help="list the sections and commands")
    parser.add_argument("--file", type=Path, default=RESULTS_FILE,
                        help=f"the results file (default {RESULTS_FILE.name} of the checkout)")


def sections(text: str, path: Path | str = RESULTS_FILE) -> list[Section]:
    """The sections of a results file, in order; InputError for one without a command."""
    out = []
    for match in SECTION.finditer(text):
        command = COMMAND.search(match["body"])
        if command is None:
            raise InputError(f"section '{match['name']}' has no line 'Command: `...`'", path)
        out.append(Section(match["name"], command["command"]))
    return out


def render(section: Section, output: str, exit_code: int, when: str) -> str:
    """The body of a section after running its command."""
    status = "" if exit_code == 0 else f" (exit code {exit_code})"
    return (f"Command: `{section.command}`\nMeasured: {when}{status}\n"
            f"```text\n{output.rstrip()}\n```\n")


def run_command(command: str) -> tuple[str, int]:
    """stdout and exit code of a section's command; `sdvl` runs this checkout's entry point."""
    argv = shlex.split(command)
    if argv and argv[0] == "sdvl":
        argv = [sys.executable, "-m", "sdvl.cli", *argv[1:]]
    elif argv and argv[0] == "python":
        argv[0] = sys.executable
    done = subprocess.run(argv, capture_output=True, text=True, check=False,
                          cwd=RESULTS_FILE.parent)
    return done.stdout, done.returncode


def machine_note() -> str:
    """Date, cores and load, for the Measured line."""
    load = os.getloadavg()[0]
    return f"{datetime.date.today().isoformat()} ({os.cpu_count()} cores, load {load:.1f})"


def regenerate(path: Path, section: Section) -> None:
    """Rerun one section's command and write its output into the file as it is now (another
    `sdvl results` may have written other sections meanwhile)."""
    print(f"sdvl results: {section.name}: {section.command}", file=sys.stderr)
    output, code = run_command(section.command)
    body = render(section, output, code, machine_note())

    def replace(match: re.Match) -> str:
        if match["name"] != section.name:
            return match[0]
        return f"<!-- section: {section.name} -->\n{body}<!-- end: {section.name} -->\n"

    path.write_text(SECTION.sub(replace, read_text(path)))


def run(args: argparse.Namespace) -> int:
    """Entry point of `sdvl results`."""
    text = read_text(args.file)
    known = sections(text, args.file)
    if args.list or not (args.names or args.all):
        for section in known:
            print(f"{section.name:28} {section.command}")
        return 0
    names = {s.name for s in known} if args.all else set(args.names)
    unknown = names - {s.name for s in known}
    if unknown:
        raise InputError(f"no section {', '.join(sorted(unknown))}; sdvl results --list "
                         "shows them", args.file)
    for section in known:
        if section.name in names:
            regenerate(args.file, section)
    return 0
