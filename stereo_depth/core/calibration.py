"""Stereo calibration from chessboard views: corners -> intrinsics -> extrinsics -> rectifying CameraInfos.

The steps are the ones the ROS camera_calibration tool and OpenCV's stereo_calib sample take: find the
inner corners in both images of a pair (sub-pixel refined), keep a pair only when both sides see the
whole board, calibrate each camera alone, then the pair with the intrinsics fixed (the mono solutions
are better conditioned than a joint 2x9-parameter fit on few views), and rectify with alpha 0 so the
rectified images hold only valid pixels. The numbers a person needs to trust the result are computed
here too: RMS reprojection errors, the row disagreement of the corners after rectification through the
very CameraInfos that get written, and how much of each image the board views covered.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.errors import CalibrationError

SUBPIX_WINDOW = (11, 11)
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-9)
_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
MIN_VIEWS = 6


@dataclass(frozen=True)
class Board:
    """A chessboard: inner corners per row (cols) and per column (rows), square edge in metres."""

    cols: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            msg = f"board {self.cols}x{self.rows}: count inner corners (at least 2x2), not squares"
            raise CalibrationError(msg)
        if not self.square > 0:
            msg = f"square size {self.square} m must be positive (metres, e.g. 0.025)"
            raise CalibrationError(msg)

    @property
    def pattern(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> np.ndarray:
        """Corner positions on the board plane (z = 0), in the row-major order OpenCV returns them."""
        grid = np.mgrid[0 : self.cols, 0 : self.rows].T.reshape(-1, 2)
        points = np.zeros((self.cols * self.rows, 3), np.float32)
        points[:, :2] = grid * self.square
        return points


@dataclass(frozen=True)
class ImagePair:
    """One stereo view as read from a folder or a bag; `name` identifies it in messages."""

    name: str
    left: np.ndarray
    right: np.ndarray


@dataclass
class Views:
    """The pairs in which both cameras saw the whole board, and why the others were dropped."""

    size: tuple[int, int]  # (width, height)
    names: list[str] = field(default_factory=list)
    left: list[np.ndarray] = field(default_factory=list)  # (N, 1, 2) float32 corners per view
    right: list[np.ndarray] = field(default_factory=list)
    rejected: list[tuple[str, str]] = field(default_factory=list)  # (name, reason)
    sample: ImagePair | None = None  # the first kept pair, for the picture (a bag is not read twice)

    def __len__(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class StereoCalibration:
    """The written result (two CameraInfos) and the raw solution it came from."""

    left: CameraInfo
    right: CameraInfo
    rms_left: float
    rms_right: float
    rms_stereo: float
    rotation: np.ndarray  # left -> right camera, 3x3
    translation: np.ndarray  # left -> right camera, metres, (3,)


def to_grey(image: np.ndarray) -> np.ndarray:
    """Corner and feature detection work on 8-bit grey; colour is converted, 16-bit scaled to its peak."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max(initial=0)), 1.0))
    return image


def find_corners(grey: np.ndarray, board: Board) -> np.ndarray | None:
    """Sub-pixel inner corners, first corner at the top, or None when the whole board is not visible.

    findChessboardCorners may start from either end of the board; a pair whose two sides start from
    different ends would pair the wrong corners, so the order is made top-first in every image.
    """
    found, corners = cv2.findChessboardCorners(grey, board.pattern, flags=_FIND_FLAGS)
    if not found:
        return None
    corners = cv2.cornerSubPix(grey, corners, SUBPIX_WINDOW, (-1, -1), _SUBPIX_CRITERIA)
    corners = corners.reshape(-1, 1, 2)  # OpenCV 5 returns (N, 2), OpenCV 4 (N, 1, 2)
    if corners[0, 0, 1] > corners[-1, 0, 1]:
        corners = np.ascontiguousarray(corners[::-1])
    return corners


def _image_size(pair: ImagePair) -> tuple[int, int]:
    left, right = pair.left.shape[:2], pair.right.shape[:2]
    if left != right:
        msg = (
            f"pair {pair.name}: left image is {left[1]}x{left[0]} but right is {right[1]}x{right[0]}; "
            "both cameras must have the same resolution"
        )
        raise CalibrationError(msg)
    return (left[1], left[0])


def detect_views(pairs: Iterable[ImagePair], board: Board) -> Views:
    """Corners in every pair; a pair is kept only when both sides show the whole board."""
    views: Views | None = None
    for pair in pairs:
        size = _image_size(pair)
        if views is None:
            views = Views(size)
        elif size != views.size:
            msg = (
                f"pair {pair.name} is {size[0]}x{size[1]} but earlier pairs are "
                f"{views.size[0]}x{views.size[1]}; all views must come from one camera mode"
            )
            raise CalibrationError(msg)
        left = find_corners(to_grey(pair.left), board)
        right = find_corners(to_grey(pair.right), board)
        if left is None or right is None:
            missing = " and ".join(s for s, c in (("left", left), ("right", right)) if c is None)
            views.rejected.append((pair.name, f"no {board.cols}x{board.rows} board found in {missing}"))
            continue
        if views.sample is None:
            views.sample = pair
        views.names.append(pair.name)
        views.left.append(left)
        views.right.append(right)
    if views is None:
        msg = "no image pairs to calibrate from"
        raise CalibrationError(msg)
    return views


def check_enough_views(views: Views, board: Board, min_views: int = MIN_VIEWS) -> None:
    """Refuse to calibrate from too few views: the distortion terms would fit noise."""
    if len(views) == 0:
        msg = (
            f"no pair shows the whole {board.cols}x{board.rows} board on both sides "
            f"({len(views.rejected)} pairs tried); --board counts inner corners (COLSxROWS)"
        )
        raise CalibrationError(msg)
    if len(views) < min_views:
        msg = (
            f"only {len(views)} of {len(views) + len(views.rejected)} pairs show the board on both sides; "
            f"need at least {min_views}: add views with the board at different positions and tilts"
        )
        raise CalibrationError(msg)


def calibrate_stereo(views: Views, board: Board, min_views: int = MIN_VIEWS) -> StereoCalibration:
    """Mono calibration of each camera, stereo calibration with fixed intrinsics, then rectification."""
    check_enough_views(views, board, min_views)
    objects = [board.object_points()] * len(views)
    size = views.size
    rms_l, k_l, d_l, _, _ = cv2.calibrateCamera(objects, views.left, size, None, None)
    rms_r, k_r, d_r, _, _ = cv2.calibrateCamera(objects, views.right, size, None, None)
    rms, _, _, _, _, rotation, translation, _, _ = cv2.stereoCalibrate(
        objects,
        views.left,
        views.right,
        k_l,
        d_l,
        k_r,
        d_r,
        size,
        flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=_SUBPIX_CRITERIA,
    )
    r_l, r_r, p_l, p_r, _, _, _ = cv2.stereoRectify(
        k_l,
        d_l,
        k_r,
        d_r,
        size,
        rotation,
        translation.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )
    width, height = size
    return StereoCalibration(
        left=CameraInfo.from_values(width, height, k_l, d_l, r_l, p_l),
        right=CameraInfo.from_values(width, height, k_r, d_r, r_r, p_r),
        rms_left=float(rms_l),
        rms_right=float(rms_r),
        rms_stereo=float(rms),
        rotation=np.asarray(rotation, dtype=np.float64),
        translation=np.asarray(translation, dtype=np.float64).ravel(),
    )


def rectify_points(points: np.ndarray, info: CameraInfo) -> np.ndarray:
    """Raw pixel positions -> positions in the rectified image that `info` (K, D, R, P) produces.

    Iterated to convergence: the default few iterations leave tenths of a pixel at the image corners
    of a strongly distorted lens, as large as the row errors this is meant to measure.
    """
    k, d, r, p = info.k, info.d, info.r, info.p
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4 spells the iterated variant this way
        rectified = cv2.undistortPointsIter(points, k, d, r, p, _UNDISTORT_CRITERIA)
    else:
        rectified = cv2.undistortPoints(points, k, d, R=r, P=p, criteria=_UNDISTORT_CRITERIA)
    return np.asarray(rectified)


def rectified_row_errors(camera: StereoCamera, views: Views) -> np.ndarray:
    """Per corner, y_left - y_right after rectification: zero for a perfect calibration."""
    errors = [
        (rectify_points(left, camera.left) - rectify_points(right, camera.right))[:, 0, 1]
        for left, right in zip(views.left, views.right, strict=True)
    ]
    return np.concatenate(errors)


def coverage(corner_sets: list[np.ndarray], size: tuple[int, int]) -> float:
    """Fraction of the image inside at least one board outline: distortion is only known where seen."""
    mask = np.zeros((size[1], size[0]), np.uint8)
    for corners in corner_sets:
        hull = cv2.convexHull(np.round(corners).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1)
    return float(np.count_nonzero(mask)) / mask.size


def side_by_side(left_rect: np.ndarray, right_rect: np.ndarray, spacing: int = 24) -> np.ndarray:
    """Rectified pair next to each other with horizontal lines: aligned rows make features sit on a line."""
    picture = cv2.cvtColor(np.hstack([to_grey(left_rect), to_grey(right_rect)]), cv2.COLOR_GRAY2BGR)
    for y in range(spacing // 2, picture.shape[0], spacing):
        cv2.line(picture, (0, y), (picture.shape[1] - 1, y), (0, 255, 0), 1)
    return picture


@dataclass(frozen=True)
class CalibrationReport:
    """The numbers that say whether a calibration can be trusted."""

    views_used: int
    rejected: list[tuple[str, str]]
    rms_left: float
    rms_right: float
    rms_stereo: float
    row_error_median: float  # |y_left - y_right| after rectification, px
    row_error_p95: float
    coverage_left: float  # fraction of the image covered by board views
    coverage_right: float
    baseline: float  # metres
    focal_px: float  # rectified

    def text(self) -> str:
        lines = [
            f"views used: {self.views_used}, rejected: {len(self.rejected)}",
            *(f"  rejected {name}: {why}" for name, why in self.rejected),
            f"RMS reprojection error: left {self.rms_left:.3f} px, right {self.rms_right:.3f} px, "
            f"stereo {self.rms_stereo:.3f} px",
            f"rectified row error |y_left - y_right| of the corners: median {self.row_error_median:.3f} px, "
            f"95% {self.row_error_p95:.3f} px",
            f"board coverage of the image: left {self.coverage_left:.0%}, right {self.coverage_right:.0%}",
            f"baseline {self.baseline:.4f} m, rectified focal length {self.focal_px:.1f} px",
        ]
        return "\n".join(lines) + "\n"


def make_report(views: Views, result: StereoCalibration) -> CalibrationReport:
    camera = StereoCamera(result.left, result.right)
    rows = np.abs(rectified_row_errors(camera, views))
    return CalibrationReport(
        views_used=len(views),
        rejected=list(views.rejected),
        rms_left=result.rms_left,
        rms_right=result.rms_right,
        rms_stereo=result.rms_stereo,
        row_error_median=float(np.median(rows)),
        row_error_p95=float(np.percentile(rows, 95)),
        coverage_left=coverage(views.left, views.size),
        coverage_right=coverage(views.right, views.size),
        baseline=camera.baseline,
        focal_px=camera.fx,
    )
