"""Fusion of the tracker's poses with the autopilot's sensors: metric scale, gravity, heading,
velocity and an honest covariance. `estimator.FusionEstimator` is the entry point, configured by
`config.FusionConfig`; this package imports nothing itself so that daemon.config can use
FusionConfig without an import cycle."""
