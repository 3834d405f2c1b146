"""Datasets, synthetic scenes, simulated autopilot, replay, metrics, and the `sdvl` command."""
