"""Tracker configuration: thesis defaults, TOML loading, clear errors for bad keys and types."""

from __future__ import annotations

import pytest

from sdvl.errors import InputError
from vo.config import TrackerConfig


def test_defaults_are_the_thesis_values():
    c = TrackerConfig()
    assert (c.pyramid_levels, c.fast_threshold, c.grid_cell) == (5, 10, 32)
    assert (c.align_max_level, c.align_min_level) == (4, 2)
    assert (c.seed_a, c.seed_b, c.convergence_L) == (10.0, 10.0, 0.1)
    assert (c.kf_min_frames, c.kf_points_ratio, c.lost_points_ratio) == (30, 0.9, 0.3)
    assert (c.quality_min_ratio, c.quality_min_matches, c.lost_after_bad) == (0.2, 20, 3)
    assert c.covisible_min_shared == 10


def test_from_toml_top_level_and_table(tmp_path):
    flat = tmp_path / "a.toml"
    flat.write_text("max_matches = 150\nepipolar_margin_px = 3\n")
    c = TrackerConfig.from_toml(flat)
    assert c.max_matches == 150 and c.epipolar_margin_px == 3.0
    table = tmp_path / "b.toml"
    table.write_text("[tracker]\nkf_min_frames = 10\nthreaded_unused = 1\n")
    with pytest.raises(InputError, match="threaded_unused"):
        TrackerConfig.from_toml(table)


@pytest.mark.parametrize(("key", "value"), [("max_matches", 1.5), ("max_matches", True),
                                            ("constant_velocity", 1), ("seed_a", "10")])
def test_wrong_types_name_the_key(key, value):
    with pytest.raises(InputError, match=key):
        TrackerConfig.from_dict({key: value})


def test_unknown_key_and_bad_file(tmp_path):
    with pytest.raises(InputError, match="fast_treshold"):
        TrackerConfig.from_dict({"fast_treshold": 10})
    bad = tmp_path / "bad.toml"
    bad.write_text("max_matches = \n")
    with pytest.raises(InputError, match=r"bad\.toml"):
        TrackerConfig.from_toml(bad)
    with pytest.raises(InputError, match="file not found"):
        TrackerConfig.from_toml(tmp_path / "missing.toml")
    with pytest.raises(InputError):
        TrackerConfig.from_dict({"align_min_level": 4, "align_max_level": 2})


def test_ransac_pixels_grow_with_a_wider_image_and_never_shrink():
    c = TrackerConfig()
    assert c.ransac_pixels(640) == c.ransac_pixels(320) == (2.0, 4.0)
    inlier, rescue = c.ransac_pixels(1241)  # KITTI's width
    assert inlier == pytest.approx(2.0 * 1241 / 640) and rescue == pytest.approx(2 * inlier)
