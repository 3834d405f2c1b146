"""Closed-loop flight (`sdvl fly`): the simulated autopilot flies a mission on our estimate, the
camera renders where the vehicle truly is, and the report says whether it is ready to fly."""
