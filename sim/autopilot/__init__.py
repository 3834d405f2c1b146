"""A simulated ArduPilot/PX4 for tests and replays: MAVLink over UDP, TCP or a pty, behaving as
the real firmware does (sim/autopilot/BEHAVIOUR.md)."""

from sim.autopilot.options import DEFAULT_STREAMS, SimOptions, configured_options
from sim.autopilot.params import Release
from sim.autopilot.simulator import Received, SimAutopilot

__all__ = ["DEFAULT_STREAMS", "Received", "Release", "SimAutopilot", "SimOptions",
           "configured_options"]
