"""`sdvl replay`: a sequence played through the whole service against a simulated autopilot in
its own process, scored on what the autopilot received."""
