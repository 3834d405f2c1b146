"""Every number a user can set has a range (issue 28: `origin.altitude_m = 1e300` killed the
housekeeping task, an unbounded setting could grow a map or a history without limit): a value
far out of it is an error naming the key, in the service's sections, the fusion's and the
tracker's."""

from __future__ import annotations

import dataclasses
import typing

import pytest

from daemon.config import SECTIONS, config_from_dict
from daemon.fusion.config import FusionConfig
from daemon.fusion.config_limits import LIMITS as FUSION_LIMITS
from sdvl.errors import InputError
from vo.config import TrackerConfig
from vo.config_limits import LIMITS as TRACKER_LIMITS


def numeric_fields(cls: type) -> list[dataclasses.Field]:
    hints = typing.get_type_hints(cls)
    return [f for f in dataclasses.fields(cls) if hints[f.name] in (int, float)]


def absurd(field: dataclasses.Field) -> list[object]:
    """Values no setting should take: far beyond any range, of the field's own type."""
    return [10**12, -10**12] if isinstance(field.default, int) else [1e300, -1e300]


SERVICE_KEYS = [(name, f) for name, cls in SECTIONS.items() for f in numeric_fields(cls)]
TRACKER_KEYS = numeric_fields(TrackerConfig)


@pytest.mark.parametrize(("cls", "limits"), [(TrackerConfig, TRACKER_LIMITS),
                                             (FusionConfig, FUSION_LIMITS)])
def test_every_number_has_a_range_holding_its_default(cls, limits):
    names = {f.name for f in numeric_fields(cls)}
    assert names == set(limits), f"give these a range: {sorted(names - set(limits))}"
    for f in numeric_fields(cls):
        assert limits[f.name].contains(f.default), f.name


@pytest.mark.parametrize(("section", "field"), SERVICE_KEYS,
                         ids=[f"{s}.{f.name}" for s, f in SERVICE_KEYS])
def test_a_service_setting_far_out_of_range_names_its_key(section, field):
    for value in absurd(field):
        with pytest.raises(InputError, match=rf"{section}\.{field.name} must be"):
            config_from_dict({section: {field.name: value}})


@pytest.mark.parametrize("field", TRACKER_KEYS, ids=[f.name for f in TRACKER_KEYS])
def test_a_tracker_setting_far_out_of_range_names_its_key(field):
    for value in absurd(field):
        with pytest.raises(InputError, match=rf"tracker\.{field.name} must be"):
            TrackerConfig.from_dict({field.name: value})


def test_limits_that_matter_for_memory_and_the_filter():
    with pytest.raises(InputError, match=r"tracker\.max_keyframes must be 3\.\.1000"):
        TrackerConfig(max_keyframes=5000)
    with pytest.raises(InputError, match=r"tracker\.seed must be 0\.\."):
        TrackerConfig(seed=-1)
    with pytest.raises(InputError, match=r"fusion\.history_s must be in \(0, 10\]"):
        FusionConfig(history_s=100.0).check()
    with pytest.raises(InputError, match=r"fusion\.scale_prior_std"):
        FusionConfig(scale_prior_std=1e200).check()
