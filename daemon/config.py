"""The service configuration: a TOML file validated at start against the dataclasses below.

Each section is a frozen dataclass; its fields (name, type, default) are the schema. Every key is
documented with its default in `example_config.toml` next to this module. The `[tracker]` table is
handed unchanged to `vo.config.TrackerConfig.from_dict`, which validates it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from daemon.fusion.config import FusionConfig
from daemon.link_url import parse_link_url
from sdvl.errors import InputError
from sdvl.tables import dataclass_from_table, read_toml, suggest

EXAMPLE_CONFIG = Path(__file__).with_name("example_config.toml")
MOUNTING_PRESETS = ("down", "forward", "custom")
OUTPUTS = ("odometry", "vision_position", "both")
LOG_LEVELS = ("debug", "info", "warning", "error")


@dataclass(frozen=True)
class CameraConfig:
    """Where frames come from and how the capture thread treats the device."""

    source: str = "0"
    calibration: str = ""
    width: int = 0
    height: int = 0
    fps: float = 30.0
    realtime: bool = True
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 8.0


@dataclass(frozen=True)
class MountingConfig:
    """How the camera sits on the vehicle, and the scale applied to VO positions."""

    preset: str = "down"
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    scale: float = 1.0


@dataclass(frozen=True)
class MavlinkConfig:
    """The autopilot link and what is sent on it."""

    link: str = "/dev/serial0,921600"
    system_id: int = 1
    component_id: int = 197
    output: str = "odometry"
    vision_speed: bool = True
    max_rate_hz: float = 50.0
    max_latency_s: float = 0.2
    heartbeat_timeout_s: float = 3.0
    statustext_interval_s: float = 1.0
    position_std_m: float = 0.1
    angle_std_rad: float = 0.05


@dataclass(frozen=True)
class OriginConfig:
    """The EKF origin the service gives an autopilot that has none (no GPS)."""

    enabled: bool = False
    latitude_deg: float = 0.0
    longitude_deg: float = 0.0
    altitude_m: float = 0.0
    resend_interval_s: float = 1.0


@dataclass(frozen=True)
class ServiceConfig:
    """Logging, the systemd status line, threads."""

    log_level: str = "info"
    status_interval_s: float = 5.0
    mapping_thread: bool = True


@dataclass(frozen=True)
class Config:
    """The whole validated configuration."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    mounting: MountingConfig = field(default_factory=MountingConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    origin: OriginConfig = field(default_factory=OriginConfig)
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
    """Values that are the right type but make no sense."""
    def need(ok: bool, message: str) -> None:
        if not ok:
            raise InputError(message, path)

    need(cfg.mounting.preset in MOUNTING_PRESETS,
         f"mounting.preset must be one of {', '.join(MOUNTING_PRESETS)}")
    angles = (cfg.mounting.roll_deg, cfg.mounting.pitch_deg, cfg.mounting.yaw_deg)
    need(cfg.mounting.preset == "custom" or not any(angles),
         "mounting.roll_deg/pitch_deg/yaw_deg are used only with mounting.preset = \"custom\"")
    need(cfg.mounting.scale > 0, "mounting.scale must be > 0")
    try:
        parse_link_url(cfg.mavlink.link)
    except InputError as exc:
        raise InputError(exc.message, path) from None
    need(cfg.mavlink.output in OUTPUTS, f"mavlink.output must be one of {', '.join(OUTPUTS)}")
    need(0 < cfg.mavlink.max_rate_hz <= 50,
         "mavlink.max_rate_hz must be in (0, 50]: autopilots use at most one sample per 20 ms")
    need(1 <= cfg.mavlink.system_id <= 255, "mavlink.system_id must be 1..255")
    need(1 <= cfg.mavlink.component_id <= 255, "mavlink.component_id must be 1..255")
    for key in ("max_latency_s", "heartbeat_timeout_s", "statustext_interval_s",
                "position_std_m", "angle_std_rad"):
        need(getattr(cfg.mavlink, key) > 0, f"mavlink.{key} must be > 0")
    need(cfg.camera.fps > 0, "camera.fps must be > 0")
    need(0 < cfg.camera.reconnect_min_s <= cfg.camera.reconnect_max_s,
         "camera.reconnect_min_s must be > 0 and <= camera.reconnect_max_s")
    need(-90 <= cfg.origin.latitude_deg <= 90, "origin.latitude_deg must be -90..90")
    need(-180 <= cfg.origin.longitude_deg <= 180, "origin.longitude_deg must be -180..180")
    need(cfg.origin.resend_interval_s > 0, "origin.resend_interval_s must be > 0")
    need(cfg.service.log_level in LOG_LEVELS,
         f"service.log_level must be one of {', '.join(LOG_LEVELS)}")
    need(cfg.service.status_interval_s > 0, "service.status_interval_s must be > 0")


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

