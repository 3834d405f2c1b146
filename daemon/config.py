"""The service configuration: a TOML file validated at start against the dataclasses below.

Each section is a frozen dataclass; its fields (name, type, default) are the schema. Every key is
documented with its default in `example_config.toml` next to this module. The `[tracker]` table is
handed unchanged to `vo.config.TrackerConfig.from_dict`, which validates it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import serial

from daemon.fusion.config import FusionConfig
from daemon.link_url import LinkKind, parse_link_url
from sdvl.errors import InputError
from sdvl.tables import bounded, check_fields, dataclass_from_table, one_of, read_toml, suggest

EXAMPLE_CONFIG = Path(__file__).with_name("example_config.toml")
MOUNTING_PRESETS = ("down", "forward", "custom")
OUTPUTS = ("odometry", "vision_position", "both")
LOG_LEVELS = ("debug", "info", "warning", "error")
MAX_IMAGE_SIDE = 8192
# POSIX rates (pyserial's list) and ArduPilot's SERIALn_BAUD values that are not among them
BAUD_RATES = frozenset(serial.Serial.BAUDRATES) | {111100, 256000}


@dataclass(frozen=True)
class CameraConfig:
    """Where frames come from and how the capture thread treats the device."""

    source: str = "0"
    calibration: str = ""
    width: int = bounded(0, 0, MAX_IMAGE_SIDE, why="0 keeps the device's default")
    height: int = bounded(0, 0, MAX_IMAGE_SIDE, why="0 keeps the device's default")
    fps: float = bounded(30.0, above=0, high=1000)
    realtime: bool = True
    # the source's depth maps go to the tracker (a depth camera, a sequence with depth):
    # metric poses from the first frame; false: monocular even where depth is there
    depth: bool = False
    # a folder: every accepted frame (and depth map) recorded in a new subfolder per start, in
    # the layout a recorded folder plays back as camera.source; empty: no recording
    record: str = ""
    reconnect_min_s: float = bounded(0.5, above=0, high=3600)
    reconnect_max_s: float = bounded(8.0, above=0, high=3600)
    # longer than a slow device's first frame (a few seconds), shorter than WatchdogSec
    stall_timeout_s: float = bounded(8.0, above=0, high=3600)


@dataclass(frozen=True)
class MountingConfig:
    """How the camera sits on the vehicle, and the scale applied to VO positions."""

    preset: str = one_of("down", MOUNTING_PRESETS)
    roll_deg: float = bounded(0.0, -360, 360)
    pitch_deg: float = bounded(0.0, -360, 360)
    yaw_deg: float = bounded(0.0, -360, 360)
    scale: float = bounded(1.0, above=0, high=1e6, why="metres per VO unit")


@dataclass(frozen=True)
class MavlinkConfig:
    """The autopilot link and what is sent on it."""

    link: str = "/dev/serial0,921600"
    system_id: int = bounded(1, 1, 255)
    component_id: int = bounded(197, 1, 255)
    autopilot_system_id: int = bounded(0, 0, 255, why="0: the first autopilot heard")
    autopilot_component_id: int = bounded(0, 0, 255, why="0: the component of its HEARTBEAT")
    output: str = one_of("odometry", OUTPUTS)
    vision_speed: bool = True
    max_rate_hz: float = bounded(50.0, above=0, high=50,
                                 why="autopilots use at most one sample per 20 ms")
    max_latency_s: float = bounded(0.2, above=0, high=10)
    heartbeat_timeout_s: float = bounded(3.0, above=0, high=600)
    statustext_interval_s: float = bounded(1.0, above=0, high=3600)
    position_std_m: float = bounded(0.1, above=0, high=1000)
    angle_std_rad: float = bounded(0.05, above=0, high=math.pi)


@dataclass(frozen=True)
class OriginConfig:
    """The EKF origin the service gives an autopilot that has none (no GPS)."""

    enabled: bool = False
    latitude_deg: float = bounded(0.0, -90, 90)
    longitude_deg: float = bounded(0.0, -180, 180)
    altitude_m: float = bounded(0.0, -1000, 10000, why="metres above mean sea level")
    resend_interval_s: float = bounded(1.0, above=0, high=3600)


@dataclass(frozen=True)
class ObstaclesConfig:
    """OBSTACLE_DISTANCE from the depth camera's maps (daemon/obstacles.py)."""

    enabled: bool = False
    # ArduPilot and PX4 drop readings older than 500 ms; 10 Hz is what their proximity expects
    rate_hz: float = bounded(10.0, above=0, high=30)
    min_m: float = bounded(0.3, 0, 10, why="the depth camera's minimum range")
    max_m: float = bounded(8.0, above=0, high=600, why="the depth camera's useful range")
    band_m: float = bounded(0.5, above=0, high=10,
                            why="obstacles are within this height of the vehicle's level")


@dataclass(frozen=True)
class ServiceConfig:
    """Logging, the systemd status line, threads."""

    log_level: str = one_of("info", LOG_LEVELS)
    status_interval_s: float = bounded(5.0, above=0, high=3600)
    mapping_thread: bool = True


@dataclass(frozen=True)
class Config:
    """The whole validated configuration."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    mounting: MountingConfig = field(default_factory=MountingConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    origin: OriginConfig = field(default_factory=OriginConfig)
    obstacles: ObstaclesConfig = field(default_factory=ObstaclesConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    tracker: dict = field(default_factory=dict)


SECTIONS: dict[str, type] = {f.name: f.default_factory for f in dataclasses.fields(Config)
                             if f.name != "tracker"}


def _build_section(name: str, cls: type, table: object, path: Path | None) -> object:
    section = dataclass_from_table(cls, table, name, path)
    if hasattr(section, "check"):  # a section with its own range checks (e.g. fusion)
        section.check(path)
    return section


def _check_ranges(cfg: Config, path: Path | None) -> None:
    """Values that are each in range but make no sense together, and the link URL."""
    def need(ok: bool, message: str) -> None:
        if not ok:
            raise InputError(message, path)

    for name in SECTIONS:
        check_fields(getattr(cfg, name), name, path)
    angles = (cfg.mounting.roll_deg, cfg.mounting.pitch_deg, cfg.mounting.yaw_deg)
    need(cfg.mounting.preset == "custom" or not any(angles),
         "mounting.roll_deg/pitch_deg/yaw_deg are used only with mounting.preset = \"custom\"")
    need(cfg.camera.reconnect_min_s <= cfg.camera.reconnect_max_s,
         "camera.reconnect_min_s must be <= camera.reconnect_max_s")
    need(not cfg.obstacles.enabled or cfg.camera.depth,
         "obstacles.enabled needs camera.depth = true: the distances come from the depth maps")
    need(cfg.obstacles.min_m < cfg.obstacles.max_m, "obstacles.min_m must be < obstacles.max_m")
    need((cfg.camera.width == 0) == (cfg.camera.height == 0),
         "camera.width and camera.height are set together (both 0: the device's default size)")
    try:
        link = parse_link_url(cfg.mavlink.link)
    except InputError as exc:
        raise InputError(exc.message, path) from None
    need(link.kind != LinkKind.SERIAL or link.baud in BAUD_RATES,
         f"mavlink.link '{cfg.mavlink.link}': {link.baud} is not a serial baud rate; use the "
         "autopilot port's SERIALn_BAUD rate, e.g. 57600, 115200, 460800 or 921600")


def config_from_dict(data: dict, path: Path | None = None) -> Config:
    """A validated Config from parsed TOML; InputError names the first bad key and the fix."""
    known = [*SECTIONS, "tracker"]
    sections = {}
    for name, table in data.items():
        if name not in known:
            raise InputError(f"unknown section '[{name}]': {suggest(name, known)}", path)
        if name == "tracker":
            if not isinstance(table, dict):
                raise InputError("[tracker] must be a table of tracker options", path)
            sections[name] = dict(table)
        else:
            sections[name] = _build_section(name, SECTIONS[name], table, path)
    cfg = Config(**sections)
    _check_ranges(cfg, path)
    return cfg


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML config file."""
    path = Path(path)
    if not path.is_file():
        raise InputError("config file not found (see daemon/example_config.toml)", path)
    data = read_toml(path)
    return config_from_dict(data, path)


def replace(cfg: Config, **sections: dict) -> Config:
    """A copy of `cfg` with some keys of some sections changed, e.g. replace(c, mavlink={...})."""
    changed = {}
    for name, values in sections.items():
        if name == "tracker":
            changed[name] = {**cfg.tracker, **values}
        else:
            changed[name] = dataclasses.replace(getattr(cfg, name), **values)
    out = dataclasses.replace(cfg, **changed)
    _check_ranges(out, None)
    return out



def changed_keys(old: Config, new: Config) -> list[str]:
    """'section.key' for every setting that differs between two configs."""
    out = [f"tracker.{k}" for k in sorted(set(old.tracker) | set(new.tracker))
           if old.tracker.get(k) != new.tracker.get(k)]
    for name in SECTIONS:
        a, b = getattr(old, name), getattr(new, name)
        out += [f"{name}.{f.name}" for f in dataclasses.fields(a)
                if getattr(a, f.name) != getattr(b, f.name)]
    return out
