"""Accuracy against ground truth, and pictures a person can read.

bad-N counts a ground-truth pixel as bad when our estimate is missing or off by more than N px;
bad-2 over estimated pixels ignores the missing ones. Ground-truth pixels are those with a finite GT
value (and inside the non-occluded mask when the scene has one).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np


@dataclass
class Accuracy:
    bad1: float
    bad2: float
    bad4: float
    bad2_est: float
    density: float
    epe: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def evaluation_mask(gt: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    valid = np.isfinite(gt)
    return valid & mask if mask is not None else valid


def accuracy(disparity: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> Accuracy:
    counted = evaluation_mask(gt, mask)
    n = int(counted.sum())
    if n == 0:
        nan = float("nan")
        return Accuracy(nan, nan, nan, nan, nan, nan)
    est = disparity[counted]
    ref = gt[counted]
    have = np.isfinite(est)
    err = np.abs(est - ref)
    n_est = int(have.sum())

    def bad(threshold: float) -> float:
        return float(np.count_nonzero(~have | (err > threshold)) / n)

    return Accuracy(
        bad1=bad(1.0),
        bad2=bad(2.0),
        bad4=bad(4.0),
        bad2_est=float(np.count_nonzero(err[have] > 2.0) / n_est) if n_est else float("nan"),
        density=n_est / n,
        epe=float(err[have].mean()) if n_est else float("nan"),
    )


def colorize_disparity(disparity: np.ndarray, max_disparity: float | None = None) -> np.ndarray:
    """TURBO colour map (near = red, far = blue), invalid pixels black; BGR uint8."""
    finite = np.isfinite(disparity)
    top = max_disparity if max_disparity else (float(disparity[finite].max()) if finite.any() else 1.0)
    norm = np.zeros(disparity.shape, np.float32)
    np.divide(disparity, np.float32(max(top, 1e-6)), out=norm, where=finite)
    scaled = (np.clip(norm, 0.0, 1.0) * 255.0).astype(np.uint8)
    picture = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    picture[~finite] = 0
    return picture


def error_map(disparity: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Green = within 1 px, yellow = within 2 px, red = worse, blue = missing, black = no ground truth."""
    counted = evaluation_mask(gt, mask)
    err = np.abs(disparity - gt)
    picture = np.zeros((*gt.shape, 3), np.uint8)
    have = counted & np.isfinite(disparity)
    picture[have & (err <= 1)] = (0, 170, 0)
    picture[have & (err > 1) & (err <= 2)] = (0, 210, 230)
    picture[have & (err > 2)] = (0, 0, 230)
    picture[counted & ~np.isfinite(disparity)] = (200, 80, 0)
    return picture


def label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy()
    cv2.rectangle(out, (0, 0), (min(out.shape[1], 12 + 9 * len(text)), 22), (0, 0, 0), -1)
    cv2.putText(out, text, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def comparison_picture(
    left: np.ndarray, gt: np.ndarray, disparity: np.ndarray, mask: np.ndarray | None, title: str
) -> np.ndarray:
    """left | ground truth | ours | error map, side by side, one shared colour scale."""
    top = float(np.nanmax(gt)) if np.isfinite(gt).any() else None
    left_bgr = left if left.ndim == 3 else cv2.cvtColor(left, cv2.COLOR_GRAY2BGR)
    panels = [
        label(left_bgr, title),
        label(colorize_disparity(gt, top), "ground truth"),
        label(colorize_disparity(disparity, top), "ours"),
        label(error_map(disparity, gt, mask), "error: green<=1 yellow<=2 red>2 blue=missing"),
    ]
    return np.hstack(panels)
