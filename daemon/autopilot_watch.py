"""Autopilot heartbeat watchdog: which autopilot is on the link, link loss and reboots."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

NOT_AUTOPILOTS = (mavlink2.MAV_TYPE_GCS, mavlink2.MAV_TYPE_ONBOARD_CONTROLLER)
REBOOT_BACKSTEP_MS = 1000  # time_boot_ms going back by more than this means a reboot


class AutopilotWatch:
    """Follows the autopilot's HEARTBEAT and boot time; returns events as they happen:
    'connected', 'lost', 'reconnected' (heartbeat back after a loss) and 'rebooted'."""

    def __init__(self, timeout_s: float):
        self.timeout_s = timeout_s
        self.system_id: int | None = None
        self.component_id = 1
        self.autopilot: int | None = None  # MAV_AUTOPILOT_ARDUPILOTMEGA (3), _PX4 (12), ...
        self.last_heartbeat: float | None = None
        self.alive = False
        self.boot_ms: int | None = None
        self.reboots = 0
        self.losses = 0

    @property
    def flavour(self) -> str:
        """'ardupilot', 'px4' or 'unknown'."""
        return {mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot",
                mavlink2.MAV_AUTOPILOT_PX4: "px4"}.get(self.autopilot, "unknown")

    def on_message(self, msg: object, now: float) -> list[str]:
        """Events caused by one received message."""
        events = []
        if (msg.get_type() == "HEARTBEAT" and msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID
                and msg.type not in NOT_AUTOPILOTS):
            if self.system_id is None:
                self.system_id, self.component_id = msg.get_srcSystem(), msg.get_srcComponent()
            if msg.get_srcSystem() == self.system_id:
                self.autopilot = msg.autopilot
                if not self.alive:
                    events.append("reconnected" if self.last_heartbeat is not None
                                  else "connected")
                self.alive, self.last_heartbeat = True, now
        boot_ms = getattr(msg, "time_boot_ms", None)
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if boot_ms is not None and source == (self.system_id, self.component_id):
            if self.boot_ms is not None and boot_ms + REBOOT_BACKSTEP_MS < self.boot_ms:
                self.reboots += 1
                events.append("rebooted")
            self.boot_ms = boot_ms
        return events

    def check(self, now: float) -> list[str]:
        """['lost'] once when no heartbeat came for timeout_s."""
        if self.alive and now - self.last_heartbeat > self.timeout_s:
            self.alive = False
            self.losses += 1
            return ["lost"]
        return []
