"""Missions for `sdvl fly`: small TOML files a user can write, read into checked steps.

A mission names the synthetic world it is flown over and lists its steps in order; each step is
a table with one action key and optional limits:

    name = "default"
    world = "hover-down"      # a synthetic preset: its world, camera and camera mounting
    steps = [
      { wait = "position" },  # autopilot | vision | position | extnav
      { mode = "GUIDED" },    # any ArduCopter mode name
      { arm = true },
      { takeoff = 3.0 },      # metres above the take-off point
      { mode = "LOITER" },
      { hold = 30.0 },        # seconds in the current mode (drift measured in truth)
      { goto = [2.0, 0.0] },  # metres north, east of the take-off point [, height up]
      { land = true },        # LAND mode, then wait until the autopilot disarms
    ]

Limits a step may carry: `timeout_s` (every step but hold), `tolerance_m` and `settle_s` (goto:
arrival by the autopilot's own estimate, then the settle time before the corner is scored).
`[[steps]]` tables work as well as the inline ones. Files: sim/flight/missions/.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from pymavlink import mavutil

from sdvl.errors import InputError
from sdvl.tables import checked_value, read_toml, suggest

MISSIONS_DIR = Path(__file__).resolve().parent / "missions"
DEFAULT_MISSION = "default"
COPTER_MODES = {name: number for number, name in mavutil.mode_mapping_acm.items()}


class Action(Enum):
    """What a step does (its action key in the file)."""

    WAIT = "wait"
    ARM = "arm"
    MODE = "mode"
    TAKEOFF = "takeoff"
    HOLD = "hold"
    GOTO = "goto"
    LAND = "land"


class WaitFor(Enum):
    """What a wait step waits for, as a ground station sees it."""

    AUTOPILOT = "autopilot"  # its HEARTBEAT, EKF started (not booting)
    VISION = "vision"  # the companion's vision messages on the link
    POSITION = "position"  # EKF_STATUS_REPORT: the autopilot has a horizontal position
    EXTNAV = "extnav"  # the autopilot says it uses external navigation


# seconds a step may take before the mission is abandoned, unless the step says otherwise
DEFAULT_TIMEOUT_S = {Action.WAIT: 60.0, Action.ARM: 10.0, Action.MODE: 3.0,
                     Action.TAKEOFF: 30.0, Action.GOTO: 30.0, Action.LAND: 60.0}
GOTO_TOLERANCE_M = 0.1  # arrival: the autopilot's own estimate this close to the target
GOTO_SETTLE_S = 2.0  # then this long before the corner is scored in truth
LIMIT_KEYS = {"timeout_s": float, "tolerance_m": float, "settle_s": float}


@dataclass(frozen=True)
class Step:
    """One checked step: `value` is the WaitFor, the mode name, the take-off height (m), the
    hold (s), the goto point (north, east, height up or None) or True (arm, land)."""

    index: int
    action: Action
    value: object
    timeout_s: float | None = None
    tolerance_m: float = GOTO_TOLERANCE_M
    settle_s: float = GOTO_SETTLE_S

    def describe(self) -> str:
        """A few words for reports: 'takeoff to 3.0 m', 'goto 2.0 N 0.0 E'."""
        a, v = self.action, self.value
        if a is Action.WAIT:
            return f"wait for {v.value}"
        if a is Action.TAKEOFF:
            return f"takeoff to {v:g} m"
        if a is Action.HOLD:
            return f"hold {v:g} s"
        if a is Action.MODE:
            return f"mode {v}"
        if a is Action.GOTO:
            north, east, height = v
            return f"goto {north:g} N {east:g} E" + ("" if height is None else f" {height:g} m")
        return a.value


@dataclass(frozen=True)
class Mission:
    """A mission as read: its name, the preset whose world it flies over, its steps."""

    name: str
    world: str
    steps: tuple[Step, ...]
    source: str = ""

    def planned_path(self) -> list[tuple[float, float, float]]:
        """The points the mission means to fly through, NED metres from the take-off point:
        the ground, the take-off height, each goto, the ground under the last point."""
        points = [(0.0, 0.0, 0.0)]
        down = 0.0
        for step in self.steps:
            north, east, _ = points[-1]
            if step.action is Action.TAKEOFF:
                down = -float(step.value)
                points.append((north, east, down))
            elif step.action is Action.GOTO:
                n, e, height = step.value
                down = down if height is None else -height
                points.append((n, e, down))
            elif step.action is Action.LAND:
                points.append((north, east, 0.0))
        return points


def mission_path(name_or_path: str) -> Path:
    """The file of a mission given by name (sim/flight/missions/NAME.toml) or path."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        return path
    known = MISSIONS_DIR / f"{name_or_path}.toml"
    if not known.exists():
        names = sorted(p.stem for p in MISSIONS_DIR.glob("*.toml"))
        raise InputError(f"no mission '{name_or_path}': give a .toml file or one of "
                         f"{', '.join(names)}")
    return known


def load_mission(name_or_path: str = DEFAULT_MISSION) -> Mission:
    """The mission of a file or a built-in name; InputError naming the step and key on a
    mistake."""
    path = mission_path(name_or_path)
    return parse_mission(read_toml(path), str(path))


def parse_mission(table: dict, source: str = "") -> Mission:
    """A Mission from a parsed TOML table (see the module doc for the format)."""
    from sim.synth.presets import PRESETS

    unknown = set(table) - {"name", "world", "steps", "description"}
    if unknown:
        key = sorted(unknown)[0]
        raise InputError(f"unknown key '{key}': {suggest(key, ['name', 'world', 'steps'])}",
                         source)
    world = checked_value("world", table.get("world", "hover-down"), str, source)
    if world not in PRESETS:
        raise InputError(f"world '{world}' is not a synthetic preset ({', '.join(PRESETS)})",
                         source)
    steps = table.get("steps")
    if not isinstance(steps, list) or not steps:
        raise InputError("steps must be a list of steps, e.g. steps = [ { arm = true } ]",
                         source)
    name = checked_value("name", table.get("name", Path(source).stem or "mission"), str,
                         source)
    return Mission(name, world, tuple(_step(i, s, source) for i, s in enumerate(steps, 1)),
                   source)


def _step(index: int, table: object, source: str) -> Step:
    """One step table: exactly one action key, then its limits."""
    where = f"step {index}"
    if not isinstance(table, dict):
        raise InputError(f"{where} must be a table such as {{ hold = 30 }}", source)
    actions = [key for key in table if key in Action._value2member_map_]
    if len(actions) != 1:
        found = ", ".join(actions) if actions else "none"
        raise InputError(f"{where} needs exactly one action key "
                         f"({', '.join(a.value for a in Action)}), found {found}", source)
    action = Action(actions[0])
    limits = {}
    for key, value in table.items():
        if key == action.value:
            continue
        if key not in LIMIT_KEYS:
            raise InputError(f"{where}: unknown key '{key}': {suggest(key, LIMIT_KEYS)}",
                             source)
        limits[key] = _positive(f"{where}.{key}", value, source)
    if action is Action.HOLD and "timeout_s" in limits:
        raise InputError(f"{where}: a hold has no timeout_s (it lasts what it says)", source)
    value = _action_value(action, table[action.value], where, source)
    timeout = limits.pop("timeout_s", DEFAULT_TIMEOUT_S.get(action))
    return Step(index, action, value, timeout, **limits)


def _positive(key: str, value: object, source: str) -> float:
    number = checked_value(key, value, float, source)
    if not number > 0:
        raise InputError(f"{key} must be more than 0, got {value!r}", source)
    return number


def _action_value(action: Action, value: object, where: str, source: str) -> object:
    """The checked value of an action key."""
    key = f"{where}.{action.value}"
    if action in (Action.ARM, Action.LAND):
        if value is not True:
            raise InputError(f"{key} must be true", source)
        return True
    if action is Action.WAIT:
        text = checked_value(key, value, str, source)
        if text not in WaitFor._value2member_map_:
            raise InputError(f"{key}: '{text}' is not one of "
                             f"{', '.join(w.value for w in WaitFor)}", source)
        return WaitFor(text)
    if action is Action.MODE:
        mode = checked_value(key, value, str, source).upper()
        if mode not in COPTER_MODES:
            raise InputError(f"{key}: '{value}' is not an ArduCopter mode "
                             f"({', '.join(COPTER_MODES)})", source)
        return mode
    if action in (Action.TAKEOFF, Action.HOLD):
        return _positive(key, value, source)
    return _goto_point(key, value, source)


def _goto_point(key: str, value: object, source: str) -> tuple[float, float, float | None]:
    if not isinstance(value, list) or len(value) not in (2, 3):
        raise InputError(f"{key} must be [north, east] or [north, east, height] in metres "
                         f"from the take-off point, got {value!r}", source)
    numbers = [checked_value(key, v, float, source) for v in value]
    if len(numbers) == 3 and numbers[2] <= 0:
        raise InputError(f"{key}: the height must be above the ground (> 0 m)", source)
    return numbers[0], numbers[1], numbers[2] if len(numbers) == 3 else None
