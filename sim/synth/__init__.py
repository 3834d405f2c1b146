"""Synthetic flights: a ray-cast textured world, smooth trajectories, imaging effects, events
and the autopilot's sensors, all from one ground truth (see `sim.synth.flight`)."""
