"""Fusion of the tracker's poses with the autopilot's sensors: metric scale, gravity, heading,
velocity and an honest covariance (see estimator.py)."""

from daemon.fusion.config import FusionConfig
from daemon.fusion.estimator import FusionEstimator

__all__ = ["FusionConfig", "FusionEstimator"]
