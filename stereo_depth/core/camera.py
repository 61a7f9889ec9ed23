"""Camera model for a calibrated stereo pair (the subset of image_geometry that stereo needs).

`CameraInfo` mirrors sensor_msgs/CameraInfo as a plain dataclass so the core never imports ROS.
`StereoCamera` checks a pair once, derives f, baseline and Q from the projection matrices, and builds
the undistort+rectify maps once per calibration: they are by far the most expensive thing to compute
and the same for every frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from stereo_depth.errors import CalibrationError

DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
OPENCV_D_SIZES = (4, 5, 8, 12, 14)  # coefficient counts cv2.initUndistortRectifyMap accepts


def _matrix(values: object, shape: tuple[int, int]) -> np.ndarray:
    return np.asarray(values, dtype=np.float64).reshape(shape)


@dataclass(frozen=True, eq=False)
class CameraInfo:
    """One camera's calibration, as in sensor_msgs/CameraInfo (row-major K 3x3, R 3x3, P 3x4)."""

    width: int
    height: int
    k: np.ndarray
    d: np.ndarray
    r: np.ndarray
    p: np.ndarray
    distortion_model: str = "plumb_bob"
    frame_id: str = ""

    @classmethod
    def from_values(
        cls,
        width: int,
        height: int,
        k: object,
        d: object,
        r: object,
        p: object,
        distortion_model: str = "plumb_bob",
        frame_id: str = "",
    ) -> CameraInfo:
        """Build from flat sequences (message fields, YAML lists); shapes are checked here."""
        try:
            return cls(
                width=int(width),
                height=int(height),
                k=_matrix(k, (3, 3)),
                d=np.asarray(d, dtype=np.float64).ravel(),
                r=_matrix(r, (3, 3)),
                p=_matrix(p, (3, 4)),
                distortion_model=str(distortion_model),
                frame_id=str(frame_id),
            )
        except (ValueError, TypeError) as exc:
            msg = f"CameraInfo has malformed matrices ({exc}); K and R need 9 values, P needs 12"
            raise CalibrationError(msg) from exc

    def key(self) -> tuple[object, ...]:
        """A hashable identity of the calibration: equal keys mean the same rectification maps."""
        return (
            self.width,
            self.height,
            self.distortion_model,
            self.k.tobytes(),
            self.d.tobytes(),
            self.r.tobytes(),
            self.p.tobytes(),
        )

    def __eq__(self, other: object) -> bool:
        return isinstance(other, CameraInfo) and self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())


def check_camera_info(info: CameraInfo, side: str) -> None:
    for name in ("k", "d", "r", "p"):
        values = getattr(info, name)
        if not np.all(np.isfinite(values)):
            msg = f"{side} camera_info: {name.upper()} contains NaN or inf; recalibrate the camera"
            raise CalibrationError(msg)
    if info.width <= 0 or info.height <= 0:
        msg = f"{side} camera_info: image size {info.width}x{info.height} is empty; set width and height"
        raise CalibrationError(msg)
    if info.p[0, 0] <= 0 or info.p[1, 1] <= 0:
        msg = f"{side} camera_info: P has no focal length (P[0,0]={info.p[0, 0]}); the camera is uncalibrated"
        raise CalibrationError(msg)
    if info.k[0, 0] <= 0 or info.k[1, 1] <= 0:
        msg = (
            f"{side} camera_info: K has no focal length (fx={info.k[0, 0]}, fy={info.k[1, 1]}); "
            "the camera is uncalibrated"
        )
        raise CalibrationError(msg)
    if info.distortion_model not in DISTORTION_MODELS and np.any(info.d):
        msg = (
            f"{side} camera_info: unknown distortion model '{info.distortion_model}'; "
            f"supported: {', '.join(DISTORTION_MODELS)}"
        )
        raise CalibrationError(msg)
    if info.distortion_model == "equidistant" and info.d.size != 4 and np.any(info.d):
        msg = f"{side} camera_info: equidistant distortion needs 4 coefficients, got {info.d.size}"
        raise CalibrationError(msg)
    if info.distortion_model != "equidistant" and info.d.size not in OPENCV_D_SIZES and np.any(info.d):
        msg = (
            f"{side} camera_info: D has {info.d.size} coefficients but OpenCV takes 4, 5, 8, 12 or 14 "
            "(plumb_bob: 5, rational_polynomial: 8); fix the calibration file"
        )
        raise CalibrationError(msg)


@dataclass(eq=False)
class StereoCamera:
    """A checked stereo pair with its rectification maps, built once and reused for every frame."""

    left: CameraInfo
    right: CameraInfo
    _maps: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        check_camera_info(self.left, "left")
        check_camera_info(self.right, "right")
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            msg = (
                f"left camera_info is {self.left.width}x{self.left.height} but right is "
                f"{self.right.width}x{self.right.height}; both cameras must have the same resolution"
            )
            raise CalibrationError(msg)
        baseline = self.baseline
        if not np.isfinite(baseline):
            msg = (
                f"right camera_info: P[0,3]={self.right.p[0, 3]} gives baseline {baseline} m; the right "
                "P must hold -fx*baseline (stereo calibration missing?)"
            )
            raise CalibrationError(msg)
        if baseline < 0:
            msg = (
                f"right camera_info: P[0,3]={self.right.p[0, 3]} puts the right camera {-baseline:.3f} m "
                "to the LEFT of the left camera; left and right topics are probably swapped (set "
                "swap_left_right), or the driver gets the sign of P[0,3] wrong (set baseline, in metres)"
            )
            raise CalibrationError(msg)

    @property
    def width(self) -> int:
        return self.left.width

    @property
    def height(self) -> int:
        return self.left.height

    @property
    def fx(self) -> float:
        return float(self.left.p[0, 0])

    @property
    def fy(self) -> float:
        return float(self.left.p[1, 1])

    @property
    def cx_left(self) -> float:
        return float(self.left.p[0, 2])

    @property
    def cx_right(self) -> float:
        return float(self.right.p[0, 2])

    @property
    def cy(self) -> float:
        return float(self.left.p[1, 2])

    @property
    def baseline(self) -> float:
        """Metres, positive for a right camera on the right: B = -P_right[0,3] / P_right[0,0]."""
        return float(-self.right.p[0, 3] / self.right.p[0, 0])

    @property
    def no_depth_reason(self) -> str | None:
        """Why this pair gives disparity but no depth (a zero baseline, as stereo_image_proc's own test
        fixtures publish), or None when Z = f * B / d is defined."""
        if self.baseline != 0:
            return None
        fix = (
            "publish the stereo calibration's right P (P[0,3] = -fx * baseline), or set the baseline parameter (metres)"
        )
        if self.left.p[0, 3] != 0:  # the left P holds the offset: it is the right camera's
            fix = f"the left camera_info has P[0,3]={self.left.p[0, 3]}: left and right look swapped, set "
            fix += "swap_left_right"
        return (
            f"right camera_info: P[0,3]={self.right.p[0, 3]} gives baseline 0 m: disparity is published, but "
            f"depth and points2 are not (Z = f * baseline / d); {fix}"
        )

    @property
    def disparity_offset(self) -> float:
        """cx_left - cx_right: subtracted once from a matched disparity before Z = f*B/d."""
        return self.cx_left - self.cx_right

    @cached_property
    def q(self) -> np.ndarray:
        """Reprojection matrix for matched (not pre-adjusted) disparities, as cv2.reprojectImageTo3D wants."""
        tx = -self.baseline
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.cx_left],
                [0.0, 1.0 * self.fx / self.fy, 0.0, -self.cy * self.fx / self.fy],
                [0.0, 0.0, 0.0, self.fx],
                [0.0, 0.0, -1.0 / tx, (self.cx_left - self.cx_right) / tx],
            ]
        )

    def key(self) -> tuple[object, ...]:
        return (self.left.key(), self.right.key())

    def shrunk(self, factor: int) -> StereoCamera:
        """The rectified pair as seen in images shrunk by `factor` (cv2.resize, INTER_AREA): for calibration
        that applies to the shrunk disparity, depth and points. Pixel centres map as x' = (x + 0.5) / factor
        - 0.5, so P (and K = P[:3, :3], no distortion, R = I: the images are already rectified) scale about them.
        """
        shift = (1.0 / factor - 1.0) / 2.0
        scale = np.array([[1.0 / factor, 0.0, shift], [0.0, 1.0 / factor, shift], [0.0, 0.0, 1.0]])

        def side(info: CameraInfo) -> CameraInfo:
            p = scale @ info.p
            return CameraInfo.from_values(
                info.width // factor,
                info.height // factor,
                p[:, :3],
                np.zeros(5),
                np.eye(3),
                p,
                "plumb_bob",
                info.frame_id,
            )

        return StereoCamera(side(self.left), side(self.right))

    def needs_rectification(self, side: str) -> bool:
        """False only when remapping would be the identity (no distortion, R = I, K = P[:3,:3])."""
        return self._sides_to_rectify[side]

    @cached_property
    def _sides_to_rectify(self) -> dict[str, bool]:
        """`needs_rectification` per side, decided once per calibration (np.allclose costs 30 us a call,
        on every frame's critical path otherwise)."""
        return {"left": needs_rectification(self.left), "right": needs_rectification(self.right)}

    def rectification_maps(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """Fixed-point maps for cv2.remap (CV_16SC2), built on first use and cached."""
        if side not in self._maps:
            self._maps[side] = build_rectification_maps(self.left if side == "left" else self.right)
        return self._maps[side]

    def rectify(self, image: np.ndarray, side: str, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        if image.shape[0] != self.height or image.shape[1] != self.width:
            msg = (
                f"{side} image is {image.shape[1]}x{image.shape[0]} but its camera_info says "
                f"{self.width}x{self.height}; the calibration does not belong to this camera mode"
            )
            raise CalibrationError(msg)
        if not self.needs_rectification(side):
            return image
        map1, map2 = self.rectification_maps(side)
        return cv2.remap(image, map1, map2, interpolation)


def rectified_input(info: CameraInfo) -> CameraInfo:
    """The calibration of an image that is rectified already, from a camera_info that may hold only P
    (K = 0, D and R empty or zero, as stereo_image_proc's own test fixtures publish): such an image lies
    in P's image plane, so K = P's left 3x3, no distortion, R = I. A full camera_info is kept as it is
    (its K, D and R still rectify a mask drawn on the raw image)."""
    if info.k[0, 0] > 0 and info.k[1, 1] > 0:
        return info
    return dataclasses.replace(info, k=info.p[:, :3].copy(), d=np.zeros(0), r=np.eye(3))


def with_baseline(info: CameraInfo, baseline: float) -> CameraInfo:
    """The right camera's calibration with P[0,3] = -fx * baseline (metres), for drivers that publish
    it zero or with the wrong sign."""
    p = info.p.copy()
    p[0, 3] = -p[0, 0] * baseline
    return dataclasses.replace(info, p=p)


def needs_rectification(info: CameraInfo) -> bool:
    """False only when remapping would be the identity (no distortion, R = I, K = P[:3,:3]).

    Public so a single-camera rectifier (rectify_node) takes exactly the same decision as the pair.
    """
    return bool(np.any(info.d) or not np.allclose(info.r, np.eye(3)) or not np.allclose(info.k, info.p[:, :3]))


def build_rectification_maps(info: CameraInfo) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-point undistort+rectify maps (CV_16SC2) for one camera, into its P's image plane."""
    size = (info.width, info.height)
    new_k = info.p[:, :3]
    distorted = bool(np.any(info.d))  # all-zero D of any length (or none) means no distortion
    if info.distortion_model == "equidistant":
        d = info.d[:4] if distorted else np.zeros(4)
        map1, map2 = cv2.fisheye.initUndistortRectifyMap(info.k, d, info.r, new_k, size, cv2.CV_16SC2)
    else:
        d = info.d if distorted else np.zeros(5)
        map1, map2 = cv2.initUndistortRectifyMap(info.k, d, info.r, new_k, size, cv2.CV_16SC2)
    return map1, map2
