"""The speckle filter run on two halves and joined must remove exactly what OpenCV's filter removes from
the whole image: regions that the cut splits are judged by their whole size."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_depth.core.speckles import SplitSpeckleFilter

INVALID = -16


def split_filter(raw: np.ndarray, middle: int, size: int, max_diff: int) -> tuple[np.ndarray, bool]:
    """The halves filtered one after the other, then joined; and whether the join changed anything."""
    out = raw.copy()
    speckles = SplitSpeckleFilter(out, middle, INVALID, size, max_diff)
    speckles.filter_rows(0, middle)
    speckles.filter_rows(middle, raw.shape[0])
    return out, speckles.join() is not None


def whole_filter(raw: np.ndarray, size: int, max_diff: int) -> np.ndarray:
    out = raw.copy()
    cv2.filterSpeckles(out, INVALID, size, max_diff)
    return out


def blobs(seed: int) -> np.ndarray:
    """Patches of similar disparity in many sizes and shapes, with noise and holes, like a matcher's output."""
    rng = np.random.default_rng(seed)
    height, width = int(rng.integers(30, 140)), int(rng.integers(20, 100))
    cell = int(rng.integers(1, 6))
    coarse = rng.integers(0, 8, (height // cell + 1, width // cell + 1)) * 16
    raw = np.repeat(np.repeat(coarse, cell, axis=0), cell, axis=1)[:height, :width]
    raw = raw + rng.integers(-2, 3, raw.shape)
    raw[rng.random(raw.shape) < rng.uniform(0.0, 0.3)] = INVALID
    return raw.astype(np.int16)


def test_split_filter_equals_the_whole_image_filter_on_random_regions() -> None:
    joined = 0
    for seed in range(300):
        raw = blobs(seed)
        rng = np.random.default_rng(seed + 1000)
        middle = int(rng.integers(1, raw.shape[0]))
        size, max_diff = int(rng.choice([1, 5, 20, 60])), int(rng.choice([0, 2, 4, 16]))
        split, changed = split_filter(raw, middle, size, max_diff)
        np.testing.assert_array_equal(split, whole_filter(raw, size, max_diff), err_msg=f"seed {seed}")
        joined += changed
    assert joined > 30  # many cases needed the join: regions the cut made look small


def test_a_region_is_kept_or_removed_by_its_whole_size_across_the_cut() -> None:
    raw = np.full((40, 30), INVALID, np.int16)
    raw[15:20, 2:4] = 100  # 10 pixels above the cut ...
    raw[20:30, 2:12] = 101  # ... joined to 100 below it: 110 pixels, kept
    raw[17:23, 20:25] = 300  # 30 pixels across the cut: a speckle
    split, changed = split_filter(raw, 20, 50, 2)
    assert changed
    assert (split[15:30, 2:4] != INVALID).all()
    assert (split[17:23, 20:25] == INVALID).all()
    np.testing.assert_array_equal(split, whole_filter(raw, 50, 2))


@pytest.mark.parametrize("middle", [0, 40])
def test_without_a_cut_it_is_the_plain_filter(middle: int) -> None:
    raw = blobs(7)[:40]
    out = raw.copy()
    speckles = SplitSpeckleFilter(out, middle, INVALID, 20, 4)
    speckles.filter_rows(0, raw.shape[0])
    assert speckles.join() is None
    np.testing.assert_array_equal(out, whole_filter(raw, 20, 4))
