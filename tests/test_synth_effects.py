"""Imaging effects: motion blur appears with fast motion only, vignetting darkens the corners by
the set amount, noise has the set level."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.synth.effects import IDEAL, Effects, finish, vignette
from sim.synth.flight import synthetic_sequence


def sharpness(image: np.ndarray) -> float:
    return float(cv2.Laplacian(image.astype(np.float32), cv2.CV_32F).var())


def test_fast_flight_is_blurred_and_hover_is_not():
    fast = synthetic_sequence("fast-down", size=(160, 120), textures="procedural")
    t = 3.5  # mid-leg at 6 m/s, 5 m up: ~5 px of motion in the 8 ms shutter
    ideal = fast.image_loader.ideal(t)[0]
    blurred = fast.image_loader.blurred(t)
    assert sharpness(blurred) < 0.7 * sharpness(ideal)
    hover = synthetic_sequence("hover-down", size=(160, 120), textures="procedural")
    t = 15.0
    np.testing.assert_array_equal(hover.image_loader.blurred(t), hover.image_loader.ideal(t)[0])


def test_vignetting_and_noise_levels():
    camera = synthetic_sequence("survey-down", 1, (160, 120), textures="procedural").camera
    v = vignette(camera, 0.25)
    assert v.max() == pytest.approx(1.0, abs=1e-3) and v.min() == pytest.approx(0.75, abs=1e-3)
    flat = np.full((120, 160), 100.0, np.float32)
    noisy = finish(flat, camera, Effects(read_noise=2.0, shot_noise=0.0, vignetting=0.0),
                   1.0, np.random.default_rng(0))
    assert noisy.astype(float).std() == pytest.approx(2.0, rel=0.1)
    clean = finish(flat, camera, IDEAL, 1.0, np.random.default_rng(0))
    assert np.all(clean == 100)
