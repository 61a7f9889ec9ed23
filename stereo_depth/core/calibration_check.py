"""Does the calibration still hold? The vertical offset of matched features in a rectified pair.

After correct rectification a scene point lies on the same row in both images, whatever its depth; a
knock to the rig, a loose lens or a wrong camera_info shows up first as a vertical offset, which ruins
block matching (it searches one row). So: ORB features in both rectified images, cross-checked
Hamming matches within a loose band of rows, refined to sub-pixel by one Lucas-Kanade step, RANSAC
on a row-offset model (dy = a + b*x + c*y) to drop the false matches, and the median |dy| of the
inliers. The model is free enough to keep the true matches of a badly rectified pair as inliers (a
model of dy = 0 would reject exactly the evidence we look for) and tight enough that wrong matches
cannot join them. A fundamental matrix, tried first, is not: on the close planar chessboard of the
OpenCV samples it took in wrong matches and reported 3.96 px where the board corners agree to 0.1 px.

The levels follow diagnostic_msgs/DiagnosticStatus (OK 0, WARN 1, ERROR 2, STALE 3); STALE means too
few matches to judge (a blank wall, darkness), not a bad calibration.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import cv2
import numpy as np

from stereo_depth.core.calibration import to_grey

WARN_PX = 0.5
ERROR_PX = 1.5
MIN_INLIERS = 20
MAX_FEATURES = 500
ROW_BAND_PX = 32.0  # matches further apart in y cannot come from a pair that is rectified at all
RANSAC_PX = 1.0
RANSAC_HYPOTHESES = 256
LK_WINDOW = (15, 15)
_LK_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)


class Level(enum.IntEnum):
    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class CalibrationCheck:
    """One frame's verdict: median |dy| of the inlier matches (px), their count, a level and a message."""

    median_dy: float  # NaN when there were too few inliers
    inliers: int
    level: Level
    message: str


def _mutual_matches(desc_l: np.ndarray, desc_r: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays (i_left, i_right) of descriptors that are each other's best allowed Hamming match.

    OpenCV's crossCheck refuses a mask, so the check is done here from one match in each direction.
    """
    mask = allowed.astype(np.uint8)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    forward = matcher.match(desc_l, desc_r, mask)
    backward = matcher.match(desc_r, desc_l, np.ascontiguousarray(mask.T))
    left_of_right = np.full(len(desc_r), -1)
    for match in backward:
        left_of_right[match.queryIdx] = match.trainIdx
    pairs = np.array([(m.queryIdx, m.trainIdx) for m in forward], dtype=np.intp).reshape(-1, 2)
    mutual = left_of_right[pairs[:, 1]] == pairs[:, 0]
    return pairs[mutual, 0], pairs[mutual, 1]


def _matched_points(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel positions of mutually best ORB matches within a band of rows: (N, 1, 2) each.

    ORB at a single scale (a rectified pair has none to bridge) is fast, but its keypoints sit on whole
    pixels; a Lucas-Kanade step started at the match refines the right position to sub-pixel, which
    a 0.5 px threshold needs. The detector is made per call (microseconds): OpenCV does not promise
    that one instance may be used from several threads, and the node calls this from one.
    """
    orb = cv2.ORB.create(nfeatures=MAX_FEATURES, nlevels=1)
    keys_l, desc_l = orb.detectAndCompute(left, None)
    keys_r, desc_r = orb.detectAndCompute(right, None)
    if desc_l is None or desc_r is None:
        return np.empty((0, 1, 2), np.float32), np.empty((0, 1, 2), np.float32)
    pts_l = np.array([k.pt for k in keys_l], dtype=np.float32)
    pts_r = np.array([k.pt for k in keys_r], dtype=np.float32)
    allowed = np.abs(pts_l[:, None, 1] - pts_r[None, :, 1]) < ROW_BAND_PX
    i_l, i_r = _mutual_matches(desc_l, desc_r, allowed)
    start_l = pts_l[i_l].reshape(-1, 1, 2)
    start_r = pts_r[i_r].reshape(-1, 1, 2)
    if len(start_l) == 0:
        return start_l, start_r
    refined, status, _ = cv2.calcOpticalFlowPyrLK(
        left,
        right,
        start_l,
        start_r.copy(),
        winSize=LK_WINDOW,
        maxLevel=0,
        criteria=_LK_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    tracked = status.ravel() == 1
    return start_l[tracked], refined[tracked]


def _row_model_inliers(pts_l: np.ndarray, pts_r: np.ndarray) -> np.ndarray:
    """Boolean mask of the matches that follow one row-offset model dy = a + b*x + c*y (RANSAC).

    A small rotation or shift of one camera moves rows by a smooth, nearly affine amount across the
    image, so three parameters describe a miscalibration and nothing else: a wrong match has to land
    within RANSAC_PX of that plane to count. All hypotheses are scored at once (no Python loop), and
    the sampling is seeded so that the node and the offline command report the same number.
    """
    count = len(pts_l)
    if count < MIN_INLIERS:
        return np.zeros(count, bool)
    dy = (pts_l[:, 0, 1] - pts_r[:, 0, 1]).astype(np.float64)
    design = np.column_stack([np.ones(count), pts_l[:, 0, 0], pts_l[:, 0, 1]]).astype(np.float64)
    samples = np.random.default_rng(0).integers(0, count, size=(RANSAC_HYPOTHESES, 3))
    systems = design[samples]
    usable = np.abs(np.linalg.det(systems)) > 1.0  # three points spanning a triangle of >= 0.5 px^2
    if not np.any(usable):
        return np.zeros(count, bool)
    planes = np.linalg.solve(systems[usable], dy[samples[usable]][..., None])[..., 0]
    residuals = np.abs(design @ planes.T - dy[:, None])
    best = residuals[:, np.argmax(np.count_nonzero(residuals < RANSAC_PX, axis=0))] < RANSAC_PX
    refit = np.linalg.lstsq(design[best], dy[best], rcond=None)[0]
    return np.asarray(np.abs(design @ refit - dy) < RANSAC_PX)


def verdict(median_dy: float, inliers: int) -> tuple[Level, str]:
    """Level and a message a user can act on."""
    if inliers < MIN_INLIERS:
        return Level.STALE, (
            f"only {inliers} reliable feature matches (need {MIN_INLIERS}); cannot judge the calibration "
            "on this view (too little texture or light)"
        )
    offset = f"rectified rows disagree by {median_dy:.2f} px (median over {inliers} matches)"
    if median_dy > ERROR_PX:
        return Level.ERROR, f"{offset}; the stereo calibration no longer holds: recalibrate the cameras"
    if median_dy >= WARN_PX:
        return Level.WARN, f"{offset}; depth quality suffers: recalibrate the cameras soon"
    return Level.OK, offset


def check_rectified_pair(left_rect: np.ndarray, right_rect: np.ndarray) -> CalibrationCheck:
    """Median vertical offset of RANSAC-inlier feature matches between two rectified images."""
    pts_l, pts_r = _matched_points(to_grey(left_rect), to_grey(right_rect))
    mask = _row_model_inliers(pts_l, pts_r)
    count = int(np.count_nonzero(mask))
    dy = np.abs(pts_l[mask, 0, 1] - pts_r[mask, 0, 1])
    median_dy = float(np.median(dy)) if count >= MIN_INLIERS else float("nan")
    level, message = verdict(median_dy, count)
    return CalibrationCheck(median_dy, count, level, message)
