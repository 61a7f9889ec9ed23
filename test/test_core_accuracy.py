"""Accuracy of each profile on real Middlebury scenes, against their ground truth.

Thresholds are what we measured with `stereo-depth eval test/data/scenes/* --profile P` plus a small
margin; a change that makes matching worse on real images fails here.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from stereo_depth.core.metrics import Accuracy, accuracy
from stereo_depth.core.option_fields import spec_of
from stereo_depth.core.params import CENSUS_BITS, CENSUS_P2_PER_BIT, StereoParams, make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import ImageError, ParameterError
from stereo_depth.formats.scenes import load_scene

from conftest import SCENES

# measured bad-2 (missing counts as bad): default 0.277/0.219/0.074, fast 0.325/0.147/0.074,
# stereo_image_proc 0.409/0.309/0.163 (artl/cones/tsukuba)
MAX_BAD2 = {
    ("default", "artl"): 0.30,
    ("default", "cones"): 0.24,
    ("default", "tsukuba"): 0.09,
    ("fast", "artl"): 0.35,
    ("fast", "cones"): 0.17,
    ("fast", "tsukuba"): 0.09,
    ("stereo_image_proc", "artl"): 0.43,
    ("stereo_image_proc", "cones"): 0.33,
    ("stereo_image_proc", "tsukuba"): 0.18,
    ("quality", "artl"): 0.13,  # measured 0.121/0.119/0.038
    ("quality", "cones"): 0.13,
    ("quality", "tsukuba"): 0.045,
}
# quality with fill_holes, every pixel estimated: measured bad-2 0.078/0.079/0.028
MAX_BAD2_FILLED = {"artl": 0.09, "cones": 0.09, "tsukuba": 0.035}


def run_profile(profile: str, scene_name: str, **overrides: Any) -> Accuracy:
    scene = load_scene(SCENES / scene_name)
    assert scene.gt is not None
    params = make_params(profile, {"disparity_range": scene.disparity_range(), **overrides})
    result = StereoPipeline(params).process(scene.left, scene.right, None, rectified=True, want_points=False)
    return accuracy(result.disparity, scene.gt, scene.mask)


@pytest.mark.parametrize(("profile", "scene"), sorted(MAX_BAD2))
def test_profile_accuracy_on_real_scene(profile: str, scene: str) -> None:
    acc = run_profile(profile, scene)
    assert acc.bad2 <= MAX_BAD2[profile, scene], acc


@pytest.mark.parametrize("scene", ["artl", "cones", "tsukuba"])
def test_quality_profile_trades_density_for_accuracy_by_confidence_and_fills_every_hole(scene: str) -> None:
    """Through StereoPipeline as the node and `process` run it: a higher confidence_threshold keeps
    fewer, better pixels (measured bad-2 of estimated 0.024/0.021/0.008 at 0.5, density 0.75-0.80);
    fill_holes estimates every pixel but those too near for the range (0.1-0.6 % of the pixels) and, favouring
    the background, lowers bad-2 overall."""
    plain = run_profile("quality", scene)
    confident = run_profile("quality", scene, confidence_threshold=0.5)
    assert confident.bad2_est < min(plain.bad2_est, 0.03) and confident.density > 0.7, (plain, confident)
    filled = run_profile("quality", scene, fill_holes=True)
    assert filled.density > 0.99 and filled.bad2 < min(plain.bad2, MAX_BAD2_FILLED[scene]), (plain, filled)


@pytest.mark.parametrize("scene", ["artl", "cones", "tsukuba"])
def test_default_profile_beats_stereo_image_proc(scene: str) -> None:
    ours, theirs = run_profile("default", scene), run_profile("stereo_image_proc", scene)
    assert ours.bad2 < theirs.bad2
    assert ours.density > theirs.density


def test_fast_profile_is_dense_and_beats_stereo_image_proc_on_average() -> None:
    scenes = ["artl", "cones", "tsukuba"]
    fast = [run_profile("fast", s) for s in scenes]
    theirs = [run_profile("stereo_image_proc", s) for s in scenes]
    assert sum(a.bad2 for a in fast) < sum(a.bad2 for a in theirs)
    assert all(a.density > 0.9 for a in fast)  # fast fills holes


def test_downsampled_matching_returns_full_size_disparity_in_full_size_pixels() -> None:
    scene = load_scene(SCENES / "cones")
    assert scene.gt is not None
    params = make_params("default", {"disparity_range": scene.disparity_range(), "downsample": 2})
    result = StereoPipeline(params).process(scene.left, scene.right, None, rectified=True, want_points=False)
    assert result.disparity.shape == scene.gt.shape
    acc = accuracy(result.disparity, scene.gt, scene.mask)
    assert acc.bad4 < 0.26  # measured 0.21 (0.21 at full size): disparities are scaled back to full-size pixels


# ---- every matcher at the corners of every range its parameters accept ------------------------------

SWEEP_BASE = {  # the profile that uses each matcher; bm without the fast profile's downsample and fill
    "bm": ("fast", {"downsample": 1, "fill_holes": False}),
    "sgbm": ("default", {}),
    "census_sgm": ("quality", {}),
}
SWEPT = (  # the parameters that change what a matcher computes (disparity_range: its upper corner)
    "correlation_window_size",
    "P1",
    "P2",
    "prefilter_size",
    "prefilter_cap",
    "texture_threshold",
    "uniqueness_ratio",
    "speckle_size",
    "speckle_range",
    "disp12_max_diff",
    "sgbm_mode",
    "min_disparity",
)
SANE_BAD2_EST = 0.30  # overflowed costs gave 0.5-0.95 of the returned pixels wrong on cones (now 0.04-0.15)
# A corner that leaves fewer pixels than this is not honoured but empty (a texture threshold no window can
# reach, a uniqueness no pixel can meet): the matcher must refuse it. The sparsest honoured corners keep
# 0.03 of cones (bm: a 255 px window; speckle_range 0, which keeps only flat blobs).
MIN_DENSITY = 0.02
# A window over an eighth of the image height averages over whole objects: accuracy then falls smoothly with
# size for every matcher (cones, 375 rows, census_sgm bad-2 of estimated: 45 px 0.12, 101 px 0.19, 255 px
# 0.37), which is the setting honoured, not arithmetic overflowing. The sweep checks the window at that size.
SANE_WINDOW = 45


def sweep_settings() -> list[tuple[str, Any]]:
    """(name, value) for each corner of the accepted ranges: the sweep's rows."""
    spec = {f.name: spec_of(f) for f in dataclasses.fields(StereoParams)}
    corners: list[tuple[str, Any]] = [("disparity_range", spec["disparity_range"].hi)]
    for name in SWEPT:
        lo, hi = spec[name].lo, spec[name].hi
        corners += [(name, type(getattr(StereoParams(), name))(v)) for v in (lo, hi)]
    corners.insert(3, ("correlation_window_size", SANE_WINDOW))
    corners.insert(7, ("P2", float(CENSUS_P2_PER_BIT * CENSUS_BITS)))  # census_sgm's largest at its window 1
    return corners


def sweep_row(matcher: str, name: str, value: Any, scene_name: str = "cones") -> tuple[str, Accuracy | None]:
    """(what happened, accuracy or None when refused) for one corner on a real scene."""
    scene = load_scene(SCENES / scene_name)
    assert scene.gt is not None
    profile, extra = SWEEP_BASE[matcher]
    overrides = {"disparity_range": scene.disparity_range(), **extra, "matcher": matcher, name: value}
    if name == "P1":  # P2 must exceed P1: the P1 corner raises P2 just above it
        overrides["P2"] = max(make_params(profile).P2, value + 1)
    try:
        params = make_params(profile, overrides)
        result = StereoPipeline(params).process(scene.left, scene.right, None, rectified=True, want_points=False)
    except (ParameterError, ImageError) as exc:
        return f"refused: {exc}", None
    acc = accuracy(result.disparity, scene.gt, scene.mask)
    return f"{acc.bad2:.3f} (est {acc.bad2_est:.3f}, density {acc.density:.3f})", acc


OPENCV_16_BIT = "leaves OpenCV's 16-bit disparity"
P1_NEEDS_P2 = "P2 100001.0 is outside"  # the P1 corner raises P2 above P1, past P2's range
# The corners each matcher refuses, each with the reason it must give; any other corner must be honoured.
REFUSED = {
    "bm": {
        ("disparity_range", 4096): OPENCV_16_BIT,
        ("correlation_window_size", 1): "too small for bm",
        ("P1", 100000.0): P1_NEEDS_P2,
        ("P2", 0.0): "must be greater than P1",
        ("texture_threshold", 10000): "above what bm's window can reach",
        ("min_disparity", -2048): OPENCV_16_BIT,
        ("min_disparity", 2048): OPENCV_16_BIT,
    },
    "census_sgm": {
        ("disparity_range", 4096): "too small to match",
        ("P1", 100000.0): P1_NEEDS_P2,
        ("P2", 0.0): "must be greater than P1",
        ("P2", 100000.0): "above what census_sgm can honour",
        ("uniqueness_ratio", 100.0): "must be below 100 for census_sgm",
        ("min_disparity", -2048): "must be >= 0 for census_sgm",
        ("min_disparity", 2048): "too small to match",
    },
    "sgbm": {
        ("disparity_range", 4096): OPENCV_16_BIT,
        ("correlation_window_size", 255): "sgbm keeps costs in 16 bits",
        ("correlation_window_size", SANE_WINDOW): "sgbm keeps costs in 16 bits",
        ("P1", 100000.0): P1_NEEDS_P2,
        ("P2", 0.0): "must be greater than P1",
        ("P2", 100000.0): "sgbm keeps costs in 16 bits",
        ("uniqueness_ratio", 100.0): "must be below 100 for sgbm",
        ("min_disparity", -2048): OPENCV_16_BIT,
        ("min_disparity", 2048): OPENCV_16_BIT,
    },
}


@pytest.mark.parametrize("matcher", sorted(SWEEP_BASE))
def test_every_accepted_corner_is_honoured_or_refused_with_its_reason(matcher: str) -> None:
    """Print the sweep (pytest -s) and check each accepted corner gives sane disparities, and that only
    the corners a matcher cannot honour are refused, each for its own reason."""
    insane, empty, refused = [], [], {}
    for name, value in sweep_settings():
        text, acc = sweep_row(matcher, name, value)
        print(f"{matcher:11s} {f'{name}={value}':32s} {text}")
        if acc is None:
            refused[name, value] = text
            continue
        if acc.density < MIN_DENSITY:
            empty.append(f"{name}={value}: {text}")
        judged = not (name == "correlation_window_size" and value > SANE_WINDOW)
        if judged and acc.density > 0 and acc.bad2_est > SANE_BAD2_EST:
            insane.append(f"{name}={value}: {text}")
    assert not empty, f"accepted, but nearly every pixel invalid (density below {MIN_DENSITY}): {empty}"
    assert not insane, insane
    assert refused.keys() == REFUSED[matcher].keys(), refused
    wrong = {corner: text for corner, text in refused.items() if REFUSED[matcher][corner] not in text}
    assert not wrong, wrong
