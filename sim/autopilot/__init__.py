"""A simulated ArduPilot/PX4 for tests and replays: MAVLink over UDP, TCP or a pty."""

from sim.autopilot.simulator import Received, SimAutopilot, SimOptions

__all__ = ["Received", "SimAutopilot", "SimOptions"]
