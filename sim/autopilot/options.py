"""How a simulated autopilot is set up: firmware, transport, which serial port the companion is
on, the parameters it has stored, and a few test conveniences."""

from __future__ import annotations

from dataclasses import dataclass, field

from sim.autopilot.dynamics import Dynamics
from sim.autopilot.params import Release, configured_values
from sim.autopilot.sensing import ImuNoise
from sim.trajectory import Trajectory

# the streams a companion typically asks for (its SET_MESSAGE_INTERVAL requests), in Hz
DEFAULT_STREAMS = {"ardupilot": {"ATTITUDE": 20, "SCALED_IMU": 50, "DISTANCE_SENSOR": 10,
                                 "SCALED_PRESSURE": 10},
                   "px4": {"ATTITUDE": 20, "HIGHRES_IMU": 50, "DISTANCE_SENSOR": 10,
                           "ALTITUDE": 10, "EXTENDED_SYS_STATE": 5}}


@dataclass
class SimOptions:
    """A fresh autopilot by default: firmware parameter defaults, nothing streamed on the
    companion's port but what the firmware sends unasked. `configured_options()` gives the
    set-up most tests and the replay want."""

    flavour: str = "ardupilot"  # or "px4"
    port: str = "udp"  # "udp", "tcp" or "pty"
    system_id: int = 1
    release: Release = Release.MASTER_2025  # ArduPilot parameter names
    companion_serial: int = 2  # ArduPilot SERIALn / PX4 TELEMn the companion is wired to
    params: dict = field(default_factory=dict)  # stored parameter values at first boot
    param_overrides: dict = field(default_factory=dict)  # applied on top of `params`
    streams: dict | None = None  # message -> Hz sent unasked whatever the parameters say
    heartbeat_hz: float | None = None  # None: the firmware's 1 Hz
    timesync_hz: float | None = None  # None: the firmware's (ArduPilot 0.1 Hz, PX4 by mode)
    ekf_ready_after_s: float = 0.0  # EKF initialised and tilt-aligned this long after boot
    supports_origin_command: bool = True  # False: MAV_CMD_DO_SET_GLOBAL_ORIGIN is UNSUPPORTED
    mavlink1: bool = False  # frame what the autopilot sends as MAVLink 1 (a misconfigured port)
    reboot_downtime_s: float = 0.5  # silence while rebooting on MAV_CMD_PREFLIGHT_REBOOT
    trajectory: Trajectory | None = None  # the scripted (open-loop) vehicle's flight
    dynamics: Dynamics | None = None  # a vehicle that flies on the model's own controllers
    imu_noise: ImuNoise = field(default_factory=ImuNoise)
    seed: int = 0
    absent: frozenset[str] = frozenset()  # sensor messages this vehicle has no sensor for

    def stored_params(self) -> dict[str, float]:
        return {**self.params, **self.param_overrides}


def configured_options(flavour: str = "ardupilot", viso_type: int = 2,
                       requested: dict | None = None, by_parameter: bool = False,
                       **changes: object) -> SimOptions:
    """An autopilot as after a correct `check-autopilot --apply` and a reboot
    (params.configured_values), the set-up for tests and replays that are not about
    configuration. Its streams run as a companion requested them (`requested`, default
    DEFAULT_STREAMS[flavour]), or with `by_parameter` as the configured stream-rate parameters
    say."""
    options = SimOptions(flavour=flavour, **changes)
    options.params = {**configured_values(flavour, options.release, options.companion_serial,
                                          viso_type), **options.params}
    if not by_parameter and options.streams is None:  # an explicit `streams=` is kept
        options.streams = dict(DEFAULT_STREAMS[flavour] if requested is None else requested)
    return options
