"""StereoPipeline: one calibrated pair in, disparity / depth / points out, with per-stage timings.

The live nodes and the offline bag tools call this same object, so both give bit-identical results.
It keeps what depends only on the calibration (rectification maps, pixel rays) and on the parameters
(the matcher) between frames, and rebuilds them only when those change.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from stereo_depth.core.block_matching import compile_kernels as compile_bm_kernels
from stereo_depth.core.block_matching import use_our_bm
from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.core.filters import apply_confidence_threshold
from stereo_depth.core.geometry import Rays, depth_to_points, disparity_to_depth
from stereo_depth.core.match_checks import MatchChecks
from stereo_depth.core.matching import Matcher, MatchResult, create_matcher, min_image_size
from stereo_depth.core.memory import keep_freed_memory
from stereo_depth.core.params import StereoParams, make_params
from stereo_depth.core.saturation import invalidate_glare, rectified_glare
from stereo_depth.core.spatial import compile_kernels as compile_spatial_kernels
from stereo_depth.core.spatial import spatial_filter
from stereo_depth.core.temporal import compile_kernels as compile_temporal_kernels
from stereo_depth.errors import ImageError

STAGES = ("rectify", "match", "filter", "depth", "points")


@dataclass
class StereoResult:
    camera: StereoCamera | None  # None: disparity only (no calibration known)
    left_rect: np.ndarray  # uint8 grey, rectified
    right_rect: np.ndarray  # uint8 grey, rectified (the calibration check compares the two)
    left_rect_color: np.ndarray | None  # uint8 BGR, rectified, when the input had colour
    disparity: np.ndarray  # float32, d = x_left - x_right (not offset-adjusted), NaN invalid
    confidence: np.ndarray | None
    depth: np.ndarray | None  # float32 metres, NaN invalid
    points: np.ndarray | None  # (H, W, 3) float32, NaN invalid
    timings_ms: dict[str, float] = field(default_factory=dict)
    too_near: np.ndarray | None = None  # bool: nearer than the range can see (None: detection off)
    glare: np.ndarray | None = None  # bool, the left image's saturated textureless area (core/saturation.py)


def to_grey8(image: np.ndarray, scale: float) -> np.ndarray:
    """The matchers want 8-bit grey: colour is converted, 16-bit scaled by `scale`."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=scale)
    return image


def _writable(image: np.ndarray) -> np.ndarray:
    """The image itself, or a copy where it is read-only (a view of a message's buffer, which the nodes pass
    on when rectification is the identity): numba compiles a variant of every kernel for read-only arrays,
    on the first frame (the census core: a minute or two, while frames are dropped), which
    `stereo-depth compile` does not build."""
    return image if image.flags.writeable else image.copy()


def _own_values(raw: np.ndarray, grey: np.ndarray, color: np.ndarray | None = None) -> np.ndarray | None:
    """The rectified image at the camera's own values where the pipeline has it (8-bit grey: the matcher's
    image; 8-bit colour: the rectified colour image), else None (`rectified_glare` rectifies the raw one)."""
    if raw.dtype != np.uint8:
        return None
    return grey if raw.ndim == 2 else color


def _grey_scale(left: np.ndarray, right: np.ndarray) -> float:
    """One 16-bit to 8-bit scale (common peak -> 255) for the pair's 16-bit images, so the pair stays
    photometrically consistent; an 8-bit partner (cameras of different kinds) is used as it is."""
    wide = [image for image in (left, right) if image.dtype != np.uint8]
    if not wide:
        return 1.0
    peak = max(*(int(image.max(initial=0)) for image in wide), 1)
    return 255.0 / peak


def _check_pair(left: np.ndarray, right: np.ndarray) -> None:
    if left.shape[:2] != right.shape[:2]:
        msg = (
            f"left image is {left.shape[1]}x{left.shape[0]} but right is {right.shape[1]}x{right.shape[0]}; "
            "a stereo pair must have one resolution"
        )
        raise ImageError(msg)
    if left.size == 0:
        msg = "image is empty (0 pixels)"
        raise ImageError(msg)


def _check_matchable(image: np.ndarray, params: StereoParams) -> None:
    """Refuse what the matcher cannot take (StereoSGBM would crash the process, not raise)."""
    min_width, min_height = min_image_size(params)
    height, width = image.shape[:2]
    if width < min_width or height < min_height:
        msg = (
            f"image of {width}x{height} (after downsample) is too small to match: it needs at least "
            f"{min_width}x{min_height} (min_disparity + disparity_range + correlation_window_size wide); "
            "use larger images or a smaller disparity_range"
        )
        raise ImageError(msg)


class StereoPipeline:
    """Reusable per-stream processor. `match` may run on several threads at once (each thread matches
    with a matcher of its own: OpenCV's keep working buffers between calls); the calibration caches
    are shared."""

    def __init__(self, params: StereoParams | None = None) -> None:
        keep_freed_memory()  # each frame's buffers reuse the last frame's pages (process-wide, see core.memory)
        self._params = (params or make_params()).validate()
        self._local = threading.local()
        self._camera: StereoCamera | None = None
        self._rays: dict[tuple[object, ...], Rays] = {}
        self._small_camera: tuple[tuple[object, ...], StereoCamera] | None = None
        self.calibrations_built = 0

    @property
    def params(self) -> StereoParams:
        return self._params

    def set_params(self, params: StereoParams) -> None:
        """Swap parameters in one assignment: a frame sees the old set or the new one."""
        self._params = params.validate()

    def camera_for(self, left: CameraInfo, right: CameraInfo) -> StereoCamera:
        """The StereoCamera for this calibration; rebuilt (maps included) only when it changes."""
        camera = self._camera
        if camera is None or camera.left != left or camera.right != right:
            camera = StereoCamera(left, right)
            self._camera = camera
            self.calibrations_built += 1
        return camera

    def process(
        self,
        left: np.ndarray,
        right: np.ndarray,
        camera: StereoCamera | None,
        *,
        rectified: bool = False,
        want_points: bool = True,
    ) -> StereoResult:
        """Every stage: `match`, then `add_geometry`."""
        result = self.match(left, right, camera, rectified=rectified)
        self.add_geometry(result, want_points=want_points)
        return result

    def match(
        self, left: np.ndarray, right: np.ndarray, camera: StereoCamera | None, *, rectified: bool = False
    ) -> StereoResult:
        """Rectify, match and filter: the result's disparity is final, its depth and points still None.

        The live node publishes the disparity at this point and leaves `add_geometry` to a second
        thread, which may run it while this one matches the next frame.
        """
        params, matcher, checks = self._matcher()
        t0 = time.perf_counter()
        _check_pair(left, right)
        scale = _grey_scale(left, right)
        color = left if left.ndim == 3 else None
        grey_l, grey_r = to_grey8(left, scale), to_grey8(right, scale)
        if not rectified:
            if camera is None:
                msg = "raw images need a calibration to be rectified"
                raise ImageError(msg)
            grey_l = camera.rectify(grey_l, "left")
            grey_r = camera.rectify(grey_r, "right")
            if color is not None:
                color = camera.rectify(color, "left")
        elif camera is not None and grey_l.shape[:2] != (camera.height, camera.width):
            msg = (
                f"rectified image is {grey_l.shape[1]}x{grey_l.shape[0]} but camera_info says "
                f"{camera.width}x{camera.height}"
            )
            raise ImageError(msg)
        t1 = time.perf_counter()
        factor = params.downsample
        grey_small, grey_r_small = (_writable(image) for image in _shrink(grey_l, grey_r, factor))
        _check_matchable(grey_small, _scaled(params, factor))
        match = matcher.compute(grey_small, grey_r_small)
        checks.apply(match, grey_small, grey_r_small)  # confidence, too-near pixels
        t2 = time.perf_counter()
        shape, raw_camera = grey_small.shape, None if rectified else camera
        if match.confidence is not None and params.confidence_threshold > 0:
            apply_confidence_threshold(match, params.confidence_threshold)
        glare = rectified_glare(
            left, _own_values(left, grey_l, color), raw_camera, "left", shape, params.saturation_level
        )
        if params.invalidate_saturated:
            right_glare = rectified_glare(
                right, _own_values(right, grey_r), raw_camera, "right", shape, params.saturation_level
            )
            invalidate_glare(match, glare, right_glare)
        if params.fill_holes:
            checks.fill(match, grey_small, params.hole_fill_radius)  # not over too-near pixels
        if params.spatial_filter:
            match.disparity = spatial_filter(match.disparity, params.spatial, grey_small)
        if factor > 1 and params.downsample_output == "processed":
            camera = self._shrunk(camera, factor) if camera is not None else None
            grey_l, grey_r = grey_small, grey_r_small
            color = _shrink_color(color, grey_small.shape) if color is not None else None
        elif factor > 1:
            _enlarge(match, grey_l.shape, factor)
            glare = _enlarged_mask(glare, grey_l.shape) if glare is not None else None
        t3 = time.perf_counter()
        timings = {"rectify": (t1 - t0) * 1000.0, "match": (t2 - t1) * 1000.0, "filter": (t3 - t2) * 1000.0}
        return StereoResult(
            camera, grey_l, grey_r, color, match.disparity, match.confidence, None, None, timings, match.too_near, glare
        )

    def _matcher(self) -> tuple[StereoParams, Matcher, MatchChecks]:
        """The current parameters, with this thread's matcher for them and what follows it."""
        params, local = self._params, self._local
        if getattr(local, "params", None) is not params:
            scaled = _scaled(params, params.downsample)
            local.params, local.matcher, local.checks = params, create_matcher(scaled), MatchChecks(scaled)
        return local.params, local.matcher, local.checks

    def add_geometry(self, result: StereoResult, *, want_points: bool = True) -> None:
        """Depth (and the organized points when `want_points`) of a `match` result, when it has a camera.

        Safe on another thread than `match`: it reads only the result and the per-calibration rays.
        """
        t0 = time.perf_counter()
        camera = result.camera
        if camera is not None:
            result.depth = disparity_to_depth(result.disparity, camera)
        t1 = time.perf_counter()
        if want_points and camera is not None and result.depth is not None:
            result.points = depth_to_points(result.depth, self.rays_for(camera))
        t2 = time.perf_counter()
        result.timings_ms.update(depth=(t1 - t0) * 1000.0, points=(t2 - t1) * 1000.0)

    def _shrunk(self, camera: StereoCamera, factor: int) -> StereoCamera:
        """The calibration of processed-size outputs, built once per calibration and factor."""
        key = (camera.key(), factor)
        if self._small_camera is None or self._small_camera[0] != key:
            self._small_camera = (key, camera.shrunk(factor))
        return self._small_camera[1]

    def rays_for(self, camera: StereoCamera) -> Rays:
        """The pixel rays of this calibration, computed once per calibration."""
        key = camera.key()
        if key not in self._rays:
            self._rays = {key: Rays.for_camera(camera)}
        return self._rays[key]


class CensusCoreLoad(NamedTuple):
    """How the census core's machine code came: in how long, and from which numba cache."""

    seconds: float
    cache: str


def warm_up_kernels(params: StereoParams | None) -> CensusCoreLoad | None:
    """Every numba kernel a stream of these parameters runs, compiled or loaded from numba's cache now,
    before its first input, rather than on the first frame, which would wait for them (a node drops the
    frames arriving meanwhile): the temporal and spatial filters', the census core's (about a second from the cache,
    one to two minutes on the first start after installing) and our BM's for this disparity count. A
    matcher switched to at run time still loads on its first frame. Returns the census core's load, or
    None when these parameters do not use it."""
    if params is not None and params.temporal_filter:
        compile_temporal_kernels()
    if params is not None and params.spatial_filter:
        compile_spatial_kernels()
    census = None
    if params is not None and params.matcher == "census_sgm":
        from stereo_depth.core.census_sgm import compile_kernels as load_census_core  # numba: census streams only

        start = time.perf_counter()
        cache = load_census_core()
        census = CensusCoreLoad(time.perf_counter() - start, cache)
    if params is not None:
        scaled = _scaled(params, params.downsample)
        if scaled.matcher == "bm" and use_our_bm(scaled):
            compile_bm_kernels((scaled.disparity_range,))
    return census


def _scaled(params: StereoParams, factor: int) -> StereoParams:
    """Matcher parameters for images shrunk by `factor` (disparities shrink with them)."""
    if factor == 1:
        return params
    span = -(-params.disparity_range // factor)
    return dataclasses.replace(
        params,
        disparity_range=max(16, -(-span // 16) * 16),
        min_disparity=params.min_disparity // factor,
        downsample=1,
    )


def output_params(params: StereoParams) -> StereoParams:
    """The parameters that describe the published disparity (DisparityImage's range, valid window, delta_d):
    at the processed size of `downsample_output: processed` those of the shrunk matcher, else `params`."""
    if params.downsample > 1 and params.downsample_output == "processed":
        return _scaled(params, params.downsample)
    return params


def nearest_disparity(params: StereoParams) -> float:
    """The largest disparity the matcher searches, in the pixels of the disparity output: where the
    nearest depth it can see lies."""
    scaled = _scaled(params, params.downsample)
    step = 1 if params.downsample_output == "processed" else params.downsample
    return float((scaled.min_disparity + scaled.disparity_range - 1) * step)


def _shrink_color(color: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    return cv2.resize(color, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def rectified_output(
    image: np.ndarray, camera: StereoCamera | None, side: str, *, rectified: bool, shape: tuple[int, ...]
) -> np.ndarray:
    """`side`'s input image as the rectified outputs carry it: rectified with that side's maps and shrunk
    to `shape` (the matched images' size) as the matcher's images are, at the camera's own bit depth.

    A 16-bit camera keeps its values: the matcher's 8-bit images are scaled by each pair's peak, which
    would make the published brightness jump between frames, and visual odometry tracks brightness."""
    if not rectified and camera is not None:
        image = camera.rectify(image, side)
    if image.shape[:2] != shape[:2]:
        image = _shrink_color(image, shape)
    return image


def _shrink(left: np.ndarray, right: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    if factor == 1:
        return left, right
    h, w = left.shape
    small = (max(1, w // factor), max(1, h // factor))
    return (
        cv2.resize(left, small, interpolation=cv2.INTER_AREA),
        cv2.resize(right, small, interpolation=cv2.INTER_AREA),
    )


def _enlarge(match: MatchResult, shape: tuple[int, ...], factor: int) -> None:
    """Back to full size: disparities scale with the image; nearest keeps NaN holes as holes."""
    size = (shape[1], shape[0])
    match.disparity = cv2.resize(match.disparity * np.float32(factor), size, interpolation=cv2.INTER_NEAREST)
    if match.confidence is not None:
        match.confidence = cv2.resize(match.confidence, size, interpolation=cv2.INTER_NEAREST)
    if match.excluded is not None:
        match.excluded = _enlarged_mask(match.excluded, shape)
    if match.too_near is not None:
        match.too_near = _enlarged_mask(match.too_near, shape)


def _enlarged_mask(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    return cv2.resize(mask.view(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0
