"""Parameters: profiles, explicit overrides, and refusal of values OpenCV would reject or twist."""

from __future__ import annotations

import pytest

from stereo_depth.core.params import PROFILES, StereoParams, make_params
from stereo_depth.errors import ParameterError


def test_stereo_image_proc_profile_reproduces_its_defaults() -> None:
    params = make_params("stereo_image_proc")
    assert (params.matcher, params.correlation_window_size, params.disparity_range) == ("bm", 15, 64)
    assert (params.prefilter_size, params.prefilter_cap, params.texture_threshold) == (9, 31, 10)
    assert (params.uniqueness_ratio, params.speckle_size, params.speckle_range) == (15.0, 100, 4)
    assert (params.P1, params.P2, params.disp12_max_diff, params.sgbm_mode) == (200.0, 400.0, 0, 0)


def test_default_profile_is_the_dataclass_defaults() -> None:
    assert make_params() == StereoParams()


def test_explicit_values_override_the_profile() -> None:
    params = make_params("fast", {"correlation_window_size": "21", "fill_holes": "false"})
    assert params.correlation_window_size == 21
    assert params.fill_holes is False
    assert params.matcher == "bm"  # the rest of the profile stays


def test_stereo_image_proc_aliases_select_the_matcher() -> None:
    assert make_params("default", {"stereo_algorithm": 0}).matcher == "bm"
    assert make_params("stereo_image_proc", {"stereo_algorithm": 1}).matcher == "sgbm"
    assert make_params("default", {"full_dp": True}).sgbm_mode == 1


@pytest.mark.parametrize(
    ("overrides", "reason"),
    [
        ({"disparity_range": 50}, "multiple of 16"),
        ({"correlation_window_size": 8}, "must be odd"),
        ({"matcher": "bm", "correlation_window_size": 3}, "too small for bm"),
        ({"P1": 900, "P2": 800}, "P2 .* greater than P1"),
        ({"matcher": "magic"}, "unknown"),
        ({"uniqueness_ratio": 120}, "outside"),
        ({"downsample": 3}, "1, 2 or 4"),
        ({"stereo_algorithm": 2}, "0 .* or 1"),
        ({"disparity_range": "many"}, "not a valid int"),
        ({"no_such_thing": 1}, "unknown parameter"),
        # settings a matcher's fixed-width arithmetic cannot hold (swept in test_core_accuracy.py)
        ({"matcher": "census_sgm", "correlation_window_size": 1, "P2": 60000}, "census_sgm can honour .* at most 1984"),
        ({"correlation_window_size": 21}, "sgbm keeps costs in 16 bits"),
        ({"P2": 33000}, "sgbm keeps costs in 16 bits"),
        ({"uniqueness_ratio": 100}, "below 100 for sgbm"),
        ({"min_disparity": -2048}, "OpenCV's 16-bit disparity"),
        ({"matcher": "bm", "disparity_range": 2048}, "OpenCV's 16-bit disparity"),
    ],
)
def test_invalid_values_are_refused_with_the_reason(overrides: dict[str, object], reason: str) -> None:
    with pytest.raises(ParameterError, match=reason):
        make_params("default", overrides)


def test_unknown_profile_names_the_known_ones() -> None:
    with pytest.raises(ParameterError, match="fast"):
        make_params("fastest")


def test_every_profile_is_valid() -> None:
    for name in PROFILES:
        make_params(name)


def test_census_sgm_takes_stereo_image_proc_window_and_large_windows_with_any_p2_in_range() -> None:
    """Window-summed census costs are shifted down to fit, so these are honoured, not refused."""
    make_params("stereo_image_proc", {"matcher": "census_sgm"})
    make_params("quality", {"correlation_window_size": 15, "P2": 55800})
