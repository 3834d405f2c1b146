"""The simulated autopilot itself over a real socket, seen from a plain MAVLink client: streams
and their values, origin handling, parameters, recording. (Its firmware behaviour, on a virtual
clock: tests/test_sim_autopilot_*.py.)"""

from __future__ import annotations

import logging
import socket
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from daemon.fusion.clock import ClockMap
from daemon.messages import MAV_CMD_DO_SET_GLOBAL_ORIGIN
from sim.autopilot import SimAutopilot, SimOptions, configured_options
from sim.autopilot.vehicle import ACCEL_LIMIT, GRAVITY
from sim.trajectory import Trajectory


class Client:
    """A bare UDP MAVLink client (system 1, component 197) of the simulator."""

    def __init__(self, sim: SimAutopilot):
        port = int(sim.url.rsplit(":", 1)[1])
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=197)
        self.parser = mavlink2.MAVLink(None)
        self.received: list[tuple[float, object]] = []

    def send(self, msg) -> None:
        self.sock.send(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    def listen(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            for msg in self.parser.parse_buffer(data) or []:
                self.received.append((time.monotonic(), msg))

    def listen_until(self, done, timeout: float = 30.0) -> None:
        """Listen until done() holds (at most `timeout` s): what a test waits for, not a
        window a frozen or starved process could miss."""
        end = time.monotonic() + timeout
        while not done() and time.monotonic() < end:
            self.listen(0.05)

    def of(self, name: str) -> list:
        return [m for _, m in self.received if m.get_type() == name]


def sent_time(arrival: float, msg) -> float:
    """When the autopilot sent `msg`: its boot-time stamp, else its arrival time."""
    if hasattr(msg, "time_usec"):
        return msg.time_usec / 1e6
    if hasattr(msg, "time_boot_ms"):
        return msg.time_boot_ms / 1e3
    return arrival


@pytest.mark.parametrize(("flavour", "streams"), [
    ("ardupilot", {"ATTITUDE": 20, "SCALED_IMU": 50, "DISTANCE_SENSOR": 10,
                   "SCALED_PRESSURE": 10}),
    ("px4", {"ATTITUDE": 20, "HIGHRES_IMU": 50, "DISTANCE_SENSOR": 10, "ALTITUDE": 10}),
])
def test_streams_rates_and_values(flavour, streams):
    with SimAutopilot(configured_options(flavour, requested=streams)) as sim:
        client = Client(sim)
        client.send(client.mav.heartbeat_encode(18, 8, 0, 0, 4))
        client.listen(2.2)
    own = {"px4": {"TIMESYNC": 10}, "ardupilot": {}}[flavour]  # PX4's Onboard mode sends it
    for name, hz in {**streams, **own}.items():
        # the interval the autopilot keeps: its own stamps where the message has one (arrival
        # times on a busy machine come in bursts), the median so a late send does not count
        times = [sent_time(t, m) for t, m in client.received if m.get_type() == name]
        assert np.median(np.diff(times)) == pytest.approx(1.0 / hz, rel=0.10), name
    beat = client.of("HEARTBEAT")[0]
    assert beat.autopilot == {"ardupilot": 3, "px4": 12}[flavour] and beat.type == 2
    for att in client.of("ATTITUDE"):
        t = att.time_boot_ms / 1000
        yaw = 2 * np.pi * t / 20.0 + np.pi / 2
        assert np.angle(np.exp(1j * (att.yaw - yaw))) == pytest.approx(0, abs=1e-3)
        assert abs(att.roll) <= 0.031 and abs(att.pitch) <= 0.031
    for d in client.of("DISTANCE_SENSOR"):
        assert 150 <= d.current_distance <= 152  # 1.5 m over the tilt
        assert d.orientation == mavlink2.MAV_SENSOR_ROTATION_PITCH_270
    if flavour == "ardupilot":
        acc_z = [m.zacc / 1000 * GRAVITY for m in client.of("SCALED_IMU")]
        pressure = [m.press_abs for m in client.of("SCALED_PRESSURE")]
    else:
        acc_z = [m.zacc for m in client.of("HIGHRES_IMU")]
        pressure = [m.abs_pressure for m in client.of("HIGHRES_IMU")]
        assert all(m.altitude_local == pytest.approx(1.5) for m in client.of("ALTITUDE"))
    assert np.mean(acc_z) == pytest.approx(-GRAVITY, abs=0.2)
    assert np.mean(pressure) == pytest.approx(1013.25 - 0.18, abs=0.02)  # 1.5 m up


def test_origin_only_once_and_only_when_the_ekf_is_ready():
    with SimAutopilot(SimOptions(ekf_ready_after_s=0.5, timesync_hz=0)) as sim:
        client = Client(sim)
        client.send(client.mav.set_gps_global_origin_encode(1, 1, 2, 3))
        client.listen(0.1)
        assert client.of("GPS_GLOBAL_ORIGIN") == [] and sim.origin is None
        client.listen_until(lambda: any("tilt alignment complete" in m.text
                                        for m in client.of("STATUSTEXT")))
        command = client.mav.command_int_encode(1, 1, 0, MAV_CMD_DO_SET_GLOBAL_ORIGIN, 0, 0,
                                                0, 0, 0, 0, 470000000, 80000000, 500.0)
        client.send(command)
        client.listen_until(lambda: len(client.of("COMMAND_ACK")) >= 1)
        client.send(client.mav.set_gps_global_origin_encode(1, 5, 6, 7))
        client.send(client.mav.command_long_encode(1, 1, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0,
                                                   49, 0, 0, 0, 0, 0, 0))
        client.listen_until(lambda: len(client.of("COMMAND_ACK")) >= 2
                            and len(client.of("GPS_GLOBAL_ORIGIN")) >= 2)
        client.listen(0.2)  # nothing more comes
    origins = client.of("GPS_GLOBAL_ORIGIN")
    assert [(o.latitude, o.longitude, o.altitude) for o in origins] == [(470000000, 80000000,
                                                                         500000)] * 2
    acks = [(a.command, a.result) for a in client.of("COMMAND_ACK")]
    assert acks == [(MAV_CMD_DO_SET_GLOBAL_ORIGIN, mavlink2.MAV_RESULT_ACCEPTED),
                    (mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAV_RESULT_ACCEPTED)]
    assert [a[1:] for a in sim.origin_attempts] == [("message", False), ("command", True),
                                                    ("message", False)]


def test_parameters_read_and_listed():
    with SimAutopilot(SimOptions(timesync_hz=0, param_overrides={"VISO_TYPE": 1})) as sim:
        client = Client(sim)
        client.send(client.mav.param_request_read_encode(1, 1, b"VISO_TYPE", -1))
        client.send(client.mav.param_request_read_encode(1, 1, b"NO_SUCH", -1))
        client.listen(0.2)
        client.send(client.mav.param_request_list_encode(1, 1))
        client.listen(0.3)
    values = client.of("PARAM_VALUE")
    # a read by name is answered with the index asked for, -1 as the uint16 field
    assert (values[0].param_id, values[0].param_value, values[0].param_index) == \
        ("VISO_TYPE", 1.0, 65535)
    assert len(values) == 1 + values[0].param_count
    assert {v.param_id for v in values[1:]} == set(sim.params)


def test_records_vision_messages_with_arrival_time():
    with SimAutopilot(SimOptions(timesync_hz=0)) as sim:
        client = Client(sim)
        before = time.monotonic()
        client.send(client.mav.vision_position_estimate_encode(123, 1, 2, 3, 0, 0, 0))
        client.send(client.mav.odometry_encode(456, 20, 12, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0,
                                               0, 0, 0, [0] * 21, [0] * 21))
        client.listen(0.1)
    vision = sim.vision
    assert [r.msg.get_type() for r in vision] == ["VISION_POSITION_ESTIMATE", "ODOMETRY"]
    assert all(before <= r.t <= time.monotonic() for r in vision)


def test_timesync_and_streams_on_one_boot_clock():
    """Like a real autopilot, TIMESYNC requests carry the boot time the streams are stamped
    with, so the service's clock mapping gets one offset from either."""
    with SimAutopilot(configured_options(timesync_hz=20)) as sim:
        client = Client(sim)
        client.send(client.mav.heartbeat_encode(18, 8, 0, 0, 4))
        client.listen_until(lambda: len(client.of("TIMESYNC")) >= 20
                            and len(client.of("SCALED_IMU")) >= 50)
    clock, by_stamps, by_timesync = ClockMap(), [], []
    for arrival, msg in client.received:
        if msg.get_type() == "SCALED_IMU":
            local = clock.to_local(msg.time_boot_ms / 1e3, arrival)
            by_stamps.append(local - msg.time_boot_ms / 1e3)
        elif msg.get_type() == "TIMESYNC":
            assert msg.tc1 == 0 and msg.ts1 / 1e9 < 5.0  # seconds since boot
            by_timesync.append(arrival - msg.ts1 / 1e9)
    assert len(by_timesync) >= 20 and len(by_stamps) >= 50
    # both are the boot instant on our clock plus a transport delay of at most a few ms
    assert by_stamps[-1] == pytest.approx(sim.boot_time, abs=0.01)
    assert min(by_timesync) == pytest.approx(sim.boot_time, abs=0.01)
    clock.set_offset(min(by_timesync))
    lags = [arrival - clock.to_local(m.time_boot_ms / 1e3, arrival)
            for arrival, m in client.received if m.get_type() == "SCALED_IMU"]
    # mapped to when it was sent: never after it arrived, usually just before
    assert min(lags) > -0.002 and np.median(lags) < 0.005


def test_absurd_motion_saturates_the_imu_like_a_real_sensor():
    t = np.arange(0.0, 2.0, 0.02)
    wild = Trajectory(t, np.column_stack([1e4 * np.sin(40 * t), 0 * t, 0 * t - 2.0]),
                      np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)))
    with SimAutopilot(configured_options(trajectory=wild, timesync_hz=0)) as sim:
        client = Client(sim)
        client.send(client.mav.heartbeat_encode(18, 8, 0, 0, 4))
        client.listen_until(lambda: len(client.of("SCALED_IMU")) >= 20)
        assert sim._thread.is_alive()
    imu = client.of("SCALED_IMU")
    assert len(imu) >= 20 and sim.skipped_messages == 0
    assert max(abs(m.xacc) for m in imu) == round(ACCEL_LIMIT / GRAVITY * 1000)


class _NanVehicle:
    def state(self, t: float) -> dict:
        nan = np.full(3, np.nan)
        return {"position": nan, "velocity": nan, "rotation": Rotation.identity(),
                "rates": nan, "specific_force": nan}


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast")
def test_unencodable_values_are_skipped_and_logged_never_fatal(caplog):
    with SimAutopilot(configured_options(timesync_hz=0)) as sim:
        sim.vehicle = _NanVehicle()
        client = Client(sim)
        client.send(client.mav.heartbeat_encode(18, 8, 0, 0, 4))
        with caplog.at_level(logging.WARNING, logger="sdvl.sim.autopilot"):
            client.listen_until(lambda: len(client.of("ATTITUDE")) >= 15
                                and sim.skipped_messages > 20)
        assert sim._thread.is_alive()
    assert sim.skipped_messages > 20
    assert len(client.of("HEARTBEAT")) >= 1 and len(client.of("ATTITUDE")) >= 15
    warned = [r.getMessage() for r in caplog.records]
    assert any(w.startswith("SCALED_IMU not sent") for w in warned)
    assert len(warned) == len(set(warned)), "one warning per message kind"
