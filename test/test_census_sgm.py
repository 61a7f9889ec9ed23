"""Census + SGM core on real Middlebury scenes: accuracy, invalid marking, confidence, hole filling.

Thresholds are the values measured with the quality setting (census 7x9, P1=20, P2=200,
p2_gamma=4, uniqueness 3 %, disp12 1, 3x3 median, speckle 100/1 px, gap closing 20/2, occlusion
margin 2, border margin 1) plus a margin, so a change that makes matching clearly worse fails while
run-to-run noise does not.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import subprocess
import sys
import time
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from stereo_depth.core import block_matching, temporal
from stereo_depth.core.census_sgm import STEPS, aggregation, census_sgm, compile_kernels, fill, fill_holes, postprocess
from stereo_depth.core.census_sgm import census as transform
from stereo_depth.core.matching import CensusSGMMatcher, create_matcher
from stereo_depth.core.metrics import evaluation_mask
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import load_scene as read_scene

from conftest import SCENES as SCENE_ROOT

PROFILE = make_params("quality")
QUALITY: dict[str, Any] = {  # the quality profile, as census_sgm keywords
    "window_size": PROFILE.correlation_window_size,
    "P1": PROFILE.P1,
    "P2": PROFILE.P2,
    "uniqueness_ratio": PROFILE.uniqueness_ratio,
    "disp12_max_diff": PROFILE.disp12_max_diff,
    "speckle_size": PROFILE.speckle_size,
    "speckle_range": PROFILE.speckle_range,
}
# census_sgm's defaults
GAPS: dict[str, Any] = {
    "gap_max": 20,
    "gap_tol": 2.0,
    "occlusion_margin": 2,
    "border_margin": 1,
    "gap_confidence": 0.2,
}


@cache
def load_scene(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """(left, right grey, gt, evaluated mask, num_disparities) of a bundled scene."""
    scene = read_scene(SCENE_ROOT / name)
    assert scene.gt is not None
    grey = [cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in (scene.left, scene.right)]
    return grey[0], grey[1], scene.gt, evaluation_mask(scene.gt, scene.mask), scene.disparity_range()


@cache
def run_scene(name: str) -> tuple[np.ndarray, np.ndarray]:
    """What the quality profile's matcher gives (census_sgm with the profile's values)."""
    left, right, _, _, nd = load_scene(name)
    result = create_matcher(dataclasses.replace(PROFILE, disparity_range=nd)).compute(left, right)
    assert result.confidence is not None
    return result.disparity, result.confidence


def bad2(disp: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> tuple[float, float, float]:
    """(bad-2 with missing counted bad, bad-2 over estimated pixels, density) on ``mask``."""
    est = mask & np.isfinite(disp)
    wrong = est & (np.abs(disp - gt) > 2.0)
    n, ne = int(mask.sum()), int(est.sum())
    return (wrong.sum() + n - ne) / n, wrong.sum() / max(ne, 1), ne / n


# measured: tsukuba 0.016/0.980, cones 0.045/0.923, artl 0.053/0.931 (bad2-est/density; 16-bit path costs
# gave 0.017/0.978, 0.045/0.924, 0.051/0.926)
SCENES = {
    "tsukuba": (0.03, 0.95),
    "cones": (0.065, 0.90),
    "artl": (0.07, 0.90),
}


@pytest.mark.parametrize(("name", "limits"), SCENES.items())
def test_accuracy_and_density_on_real_scenes(name: str, limits: tuple[float, float]) -> None:
    _, _, gt, mask, _ = load_scene(name)
    disp, _ = run_scene(name)
    _, bad_est, density = bad2(disp, gt, mask)
    assert bad_est <= limits[0]
    assert density >= limits[1]


@pytest.mark.parametrize("name", SCENES)
def test_invalid_pixels_are_nan_with_zero_confidence(name: str) -> None:
    left, _, _, _, nd = load_scene(name)
    disp, conf = run_scene(name)
    assert disp.dtype == np.float32 and conf.dtype == np.float32
    assert disp.shape == conf.shape == left.shape
    holes = np.isnan(disp)
    assert holes.any(), "LR check and uniqueness must reject something on a real scene"
    assert not np.isinf(disp).any()
    assert np.all(conf[holes] == 0.0)
    assert conf.min() >= 0.0 and conf.max() <= 1.0
    valid = disp[~holes]
    assert valid.min() >= -0.5 and valid.max() <= nd - 0.5
    # every pixel that has a value has a confidence: measured ones > 0, closed gaps the gap value
    assert np.all(conf[~holes] > 0.0)


def test_left_border_without_a_match_is_a_hole_unless_border_filled() -> None:
    left, right, _, _, nd = load_scene("tsukuba")
    no_border_fill = QUALITY | GAPS | {"border_margin": -1}
    unfilled, _ = census_sgm(left, right, min_disparity=0, num_disparities=nd, **no_border_fill)
    # columns left of the smallest possible match have no right pixel: outside the search range
    assert np.isnan(unfilled[:, 0]).all()
    filled, conf = run_scene("tsukuba")
    for y in np.flatnonzero(np.isfinite(filled[:, 0])):
        end = int(np.argmax(np.isfinite(unfilled[y])))  # first measured pixel of the row
        # the strip is no wider than the disparity beside it (+ margin) and takes that value
        assert end <= unfilled[y, end] + GAPS["border_margin"]
        np.testing.assert_array_equal(filled[y, :end], unfilled[y, end])
        assert np.all(conf[y, :end] == pytest.approx(0.2))


def test_close_gaps_interpolates_short_consistent_runs_only() -> None:
    disp = np.full((8, 64), np.nan, np.float32)
    disp[0, 10:40] = 20.0
    disp[0, 15:19] = np.nan  # short, both sides 20 -> interpolated
    disp[1, 30:64] = 10.0
    disp[1, 5:8] = 10.5  # bounds 10.5 and 10 but 22 px apart -> too long, stays
    disp[2, 20:30] = 12.0
    disp[2, 34:50] = 20.0  # 4 px gap before a surface 8 px nearer: occlusion -> background 12
    disp[3, 20:30] = 12.0
    disp[3, 45:50] = 20.0  # 15 px gap, step only 8: not occlusion-shaped -> stays
    disp[4, 5:20] = 6.0  # 5 px left strip beside disparity 6: border strip -> 6
    disp[5, 12:20] = 6.0  # 12 px strip beside disparity 6: too wide -> stays
    out = _close_gaps_only(disp)
    np.testing.assert_allclose(out[0, 15:19], 20.0)
    assert np.isnan(out[1, 8:30]).all()
    np.testing.assert_array_equal(out[2, 30:34], 12.0)
    assert np.isnan(out[3, 30:45]).all()
    np.testing.assert_array_equal(out[4, :5], 6.0)
    assert np.isnan(out[5, :12]).all()
    # runs that touch the right border have a single bound and are never closed
    assert np.isnan(out[0, 40:]).all()


def _close_gaps_only(disp: np.ndarray) -> np.ndarray:
    """Run just the gap-closing stage (the kernel ``census_sgm`` calls) with its default settings."""
    from stereo_depth.core.census_sgm import aggregation, postprocess, registry

    registry.compile_all()
    coded = np.where(np.isnan(disp), aggregation.HOLE, disp).astype(np.float32)
    gaps = (
        GAPS["gap_max"],
        np.float32(GAPS["gap_tol"]),
        GAPS["occlusion_margin"],
        GAPS["border_margin"],
        np.float32(GAPS["gap_confidence"]),
    )
    return postprocess._finish(coded, np.zeros_like(coded), aggregation.HOLE, gaps)


# (paths, min_disparity, num_disparities): counts that are no multiple of a vector width, and the common ones
ODD = [(8, 0, 24), (8, 3, 37), (4, 0, 24), (8, 0, 70), (6, 0, 24), (6, 3, 37), (6, 0, 70), (5, 0, 24), (5, 3, 37)]
COMMON = [(6, 0, 64), (8, 3, 64), (4, 0, 64), (6, 0, 128)]


@pytest.mark.parametrize(("paths", "min_disparity", "num_disparities"), [*ODD, *COMMON])
def test_core_computes_exactly_what_the_plain_reference_defines(
    paths: int, min_disparity: int, num_disparities: int
) -> None:
    """The numba core (8-bit paths, meeting sweeps or row strips, right view off the left's row) against plain numpy.

    A real Tsukuba crop (its left border included, so the clamped costs and the edge rule count),
    disparity counts that are no multiple of a vector width and the common ones (64, 128); an odd
    height and width, so the 6-path mode's coarse path from below has a row and a column of its own
    at the borders; the post-processing filters are off, since they run after the matching this checks.
    """
    import sgm_reference

    left, right, _, _, _ = load_scene("tsukuba")
    crop = (slice(120, 167), slice(0, max(97, num_disparities + 33)))  # wide enough for 128 to be searched
    settings: dict[str, Any] = {"P1": 20, "P2": 200, "uniqueness_ratio": 3, "disp12_max_diff": 1}
    ours, our_conf = census_sgm(
        left[crop],
        right[crop],
        min_disparity=min_disparity,
        num_disparities=num_disparities,
        window_size=1,
        paths=paths,
        median=False,
        speckle_size=0,
        gap_max=0,
        occlusion_margin=-1,
        border_margin=-1,
        **settings,
    )
    expected, expected_conf = sgm_reference.match(
        left[crop],
        right[crop],
        min_disparity=min_disparity,
        num_disparities=num_disparities,
        paths=paths,
        **settings,
    )
    assert 0.3 < np.isfinite(expected).mean() < 1.0  # a real mix of matches and rejected pixels
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(expected))
    np.testing.assert_allclose(ours, expected, atol=1e-4)
    np.testing.assert_allclose(our_conf, expected_conf, atol=1e-4)


@pytest.mark.parametrize(("paths", "num_disparities"), [(8, 64), (8, 128), (8, 40), (6, 128), (6, 40)])
def test_costs_summed_beforehand_take_the_path_of_their_own_to_the_same_answer(
    paths: int, num_disparities: int
) -> None:
    """window_size > 1 box-sums a cost volume first and the kernels read it (the sweeps and the path from
    below with ``census`` None, the strips' one-copy kernel of their own); on the window-1 volume they must
    give the census-fed answer exactly."""
    from stereo_depth.core.census_sgm import aggregation, census

    left, right, _, _, _ = load_scene("tsukuba")
    left, right = np.ascontiguousarray(left[100:196, :224]), np.ascontiguousarray(right[100:196, :224])
    compile_kernels()
    cl, cr = census.census_pair(left, right, census.CENSUS_SIZE)
    shift, p1, p2 = aggregation.cost_shift(62, 1, 20.0, 200.0)
    select = (0, 0.03, 1, 1.5, 0.5)
    sgm = (p1, p2, 4.0, paths)
    shape = (*left.shape, num_disparities)
    costs = np.empty(shape, np.uint8)
    aggregation._hamming_volume(cl, cr, 0, costs)
    answers = []
    for vol, pair in ((np.empty(shape, np.uint8), (cl, cr)), (costs >> np.uint8(shift), None)):
        if paths == 8:
            sums = np.empty(shape, np.uint16)
            answers.append(aggregation._aggregate_select(vol, pair, shift, left, sums, sgm, select))
        else:
            up = aggregation._bottom_up(vol, pair, shift, left, sgm, 0)
            if pair is None:
                answers.append(aggregation._strips_select_volume(vol, left, sgm, select, up))
            else:
                answers.append(aggregation._strips_select(vol, pair, shift, left, sgm, select, up))
    fused, summed = answers
    assert (fused[0] > 0).mean() > 0.5  # matches, not an empty answer both ways
    np.testing.assert_array_equal(summed[0], fused[0])
    np.testing.assert_array_equal(summed[1], fused[1])


@pytest.mark.parametrize("name", SCENES)
def test_confident_pixels_are_more_accurate(name: str) -> None:
    _, _, gt, mask, _ = load_scene(name)
    disp, conf = run_scene(name)
    _, bad_all, _ = bad2(disp, gt, mask)
    _, bad_conf, _ = bad2(np.where(conf >= 0.5, disp, np.nan), gt, mask)
    assert bad_conf <= 0.65 * bad_all  # measured ratios 0.48 (tsukuba), 0.44 (cones), 0.46 (artl)


@pytest.mark.parametrize("name", SCENES)
def test_fill_holes_gives_full_density_and_improves_bad2(name: str) -> None:
    left, _, gt, mask, _ = load_scene(name)
    disp, _ = run_scene(name)
    filled = fill_holes(disp, left)
    assert np.isfinite(filled).all()
    before, _, _ = bad2(disp, gt, mask)
    after, _, density = bad2(filled, gt, mask)
    assert density == 1.0
    assert after < before
    # valid pixels are left untouched
    valid = np.isfinite(disp)
    np.testing.assert_array_equal(filled[valid], disp[valid])


def test_fill_holes_background_wins_in_a_row_gap() -> None:
    disp = np.array([[10.0, np.nan, np.nan, 30.0]], np.float32)
    left = np.full((1, 4), 100, np.uint8)
    np.testing.assert_array_equal(fill_holes(disp, left, radius=0), [[10.0, 10.0, 10.0, 30.0]])


def test_the_matcher_reports_each_step_and_the_steps_account_for_its_time() -> None:
    """The matcher reports every step of census_sgm (step_ms), none counted twice or left out."""
    left, right, _, _, nd = load_scene("cones")
    matcher = create_matcher(dataclasses.replace(PROFILE, disparity_range=nd))
    assert isinstance(matcher, CensusSGMMatcher)
    matcher.compute(left, right)  # loads the kernels
    start = time.perf_counter()
    matcher.compute(left, right)
    call_ms = (time.perf_counter() - start) * 1000.0
    steps = matcher.step_ms
    assert tuple(steps) == STEPS
    assert all(ms >= 0.0 for ms in steps.values())
    # the steps lie inside the call and fill most of it (a lower bound loose enough for a preempted thread)
    assert 0.5 * call_ms <= sum(steps.values()) <= call_ms


def test_min_disparity_shifts_the_answer() -> None:
    left, right, gt, mask, nd = load_scene("tsukuba")
    disp, _ = census_sgm(left, right, min_disparity=4, num_disparities=nd - 16, **QUALITY)
    _, bad_est, density = bad2(disp, gt, mask)
    assert np.nanmin(disp) >= 3.5
    assert bad_est <= 0.035 and density >= 0.9


def test_rejects_colour_input() -> None:
    img = np.zeros((20, 30, 3), np.uint8)
    with pytest.raises(ValueError, match="uint8 grey"):
        census_sgm(img, img, min_disparity=0, num_disparities=16, **QUALITY)


@pytest.mark.parametrize(
    ("keywords", "message"),
    [({"min_disparity": -1}, "min_disparity"), ({"num_disparities": 0}, "num_disparities"), ({"paths": 7}, "paths")],
)
def test_rejects_settings_the_kernels_cannot_honour(keywords: dict[str, int], message: str) -> None:
    img = np.zeros((20, 30), np.uint8)
    settings: dict[str, Any] = {"min_disparity": 0, "num_disparities": 16, **QUALITY, **keywords}
    with pytest.raises(ValueError, match=message):
        census_sgm(img, img, **settings)


def numba_cache_name(source_folder: Path) -> str:
    """The folder numba gives a source folder's kernels under NUMBA_CACHE_DIR."""
    return f"{source_folder.name}_{hashlib.sha1(str(source_folder).encode()).hexdigest()}"


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_compile_command_builds_the_core_ahead_and_names_its_cache(tmp_path: Path, jobs: str) -> None:
    """Into a cache of its own (NUMBA_CACHE_DIR, which numba prefers) holding this session's kernels but
    two (numba loads the rest: same sources, same numba; the big ones take minutes to build), `stereo-depth
    compile` must build the two missing ones (the census transform, the hole filler) and name that cache,
    in one process or split over two (each share builds the census transform; only one the filler)."""
    core = Path(__file__).resolve().parents[1] / "stereo_depth" / "core"
    cache = tmp_path / "numba" / numba_cache_name(core / "census_sgm")
    missing = ("census._census-*", "fill._fill_rows-*")
    shutil.copytree(compile_kernels(), cache, ignore=shutil.ignore_patterns(*missing, "*.pyc"))
    temporal.compile_kernels()  # the command builds these too: theirs is the core folder's cache
    temporal_cache = Path(temporal._kernels()["store"]._cache._cache_path)  # type: ignore[attr-defined]
    shutil.copytree(temporal_cache, tmp_path / "numba" / numba_cache_name(core), ignore=shutil.ignore_patterns("*.pyc"))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    run = subprocess.run(
        [sys.executable, "-m", "stereo_depth.cli", "compile", "--jobs", jobs],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert f"({jobs} processes)" in run.stdout
    assert Path(run.stdout.strip().rsplit("numba cache: ", 1)[1]) == cache
    for kernel in missing:
        assert any(cache.glob(f"{kernel}.nbc")), f"{kernel}: its machine code must be cached"


@pytest.mark.parametrize("profile", ["quality", "stereo_image_proc"])
def test_a_read_only_frame_runs_the_kernels_compiled_ahead(profile: str) -> None:
    """A node passes the image of its message's buffer (read-only) on when rectification is the identity
    (pre-rectified cameras). numba compiles a variant of a kernel for read-only arrays, on that first frame
    (the census core: a minute or two, while every frame is dropped), which `stereo-depth compile` does not
    build: the kernels must get writable arrays."""
    from numba import types  # loaded by the census core already

    scene = read_scene(SCENE_ROOT / "cones")
    left, right = (cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in (scene.left, scene.right))
    for image in (left, right):
        image.setflags(write=False)
    pipeline = StereoPipeline(make_params(profile, {"fill_holes": True}))
    assert np.isfinite(pipeline.match(left, right, None, rectified=True).disparity).mean() > 0.5
    modules = [aggregation, transform, postprocess, fill, block_matching]
    dispatchers = [obj for module in modules for obj in vars(module).values() if hasattr(obj, "signatures")]
    dispatchers.append(block_matching._prefilter_kernel())
    assert len(dispatchers) > 5
    read_only = [
        (dispatcher, signature)
        for dispatcher in dispatchers
        for signature in dispatcher.signatures
        if any(isinstance(argument, types.Array) and not argument.mutable for argument in signature)
    ]
    assert read_only == []
