"""Synthetic frames are consistent over time: optical flow between consecutive frames agrees
with the flow the depth map and the ground-truth motion predict."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.synth.flight import synthetic_sequence


def predicted_flow_errors(seq, i: int) -> np.ndarray:
    """|LK flow - flow from depth and ground truth| (px) at corners of frame i."""
    render = seq.image_loader
    a, b = seq.image(i), seq.image(i + 1)
    _, depth = render.ideal(float(seq.timestamps[i]))
    corners = cv2.goodFeaturesToTrack(a, 300, 0.01, 8).reshape(-1, 2)
    px = np.round(corners)
    z = depth[px[:, 1].astype(int), px[:, 0].astype(int)]
    rays = seq.camera.unproject(px)
    points_a = rays * (z / rays[:, 2])[:, None]
    T = seq.groundtruth.matrices()
    T_b_a = np.linalg.inv(T[i + 1]) @ T[i]
    predicted = seq.camera.project(points_a @ T_b_a[:3, :3].T + T_b_a[:3, 3])
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(
        a, b, px.astype(np.float32), None, winSize=(15, 15), maxLevel=3,
        criteria=(cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
    ok = status.ravel().astype(bool) & seq.camera.in_image(predicted, margin=10)
    return np.linalg.norm(tracked[ok] - predicted[ok], axis=1)


@pytest.mark.parametrize(("preset", "frames"), [
    ("survey-down", (150, 400, 700)),
    ("hover-down", (30, 250, 400)),  # climbing, then turning
    ("room-handheld", (50, 300, 500)),  # forward-looking, distorted camera
])
def test_lk_flow_matches_ground_truth_flow(preset, frames):
    seq = synthetic_sequence(preset, size=(320, 240), textures="procedural")
    errors = np.concatenate([predicted_flow_errors(seq, i) for i in frames])
    assert errors.size > 300
    assert np.median(errors) < 0.3, f"median {np.median(errors):.3f} px"
