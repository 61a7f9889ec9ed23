"""`metrics.accuracy`, which scores every accuracy test and `stereo-depth eval`, on numbers worked by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereo_depth.core.metrics import accuracy

NAN = np.nan


def test_accuracy_scores_errors_and_holes_over_the_pixels_with_ground_truth_and_in_the_mask() -> None:
    gt = np.array([[10, 10, 10, 10, 10], [10, 10, NAN, 10, 10]], np.float32)
    mask = np.ones(gt.shape, bool)
    mask[1, 4] = False
    disparity = np.array([[10.5, 11.5, 13, 15, NAN], [10, 10, 50, 8, 0]], np.float32)
    # counted: 8 pixels (no ground truth at [1, 2], masked out at [1, 4]); errors 0.5 1.5 3 5 0 0 2 and a hole
    acc = accuracy(disparity, gt, mask)
    assert acc.bad1 == pytest.approx(5 / 8)  # the hole and 1.5, 3, 5, 2
    assert acc.bad2 == pytest.approx(3 / 8)  # the hole and 3, 5: an error of exactly 2 px is not bad-2
    assert acc.bad4 == pytest.approx(2 / 8)
    assert acc.bad2_est == pytest.approx(2 / 7)  # of the 7 estimated pixels
    assert acc.density == pytest.approx(7 / 8)
    assert acc.epe == pytest.approx(12 / 7)
    assert accuracy(disparity, gt).bad2 == pytest.approx(4 / 9)  # without the mask [1, 4] counts (error 10)


def test_accuracy_without_counted_or_estimated_pixels_is_nan_not_zero() -> None:
    gt = np.full((2, 3), NAN, np.float32)
    assert all(math.isnan(v) for v in accuracy(np.zeros((2, 3), np.float32), gt).as_dict().values())
    holes = accuracy(np.full((2, 3), NAN, np.float32), np.ones((2, 3), np.float32))
    assert holes.bad2 == 1.0 and holes.density == 0.0
    assert math.isnan(holes.bad2_est) and math.isnan(holes.epe)
