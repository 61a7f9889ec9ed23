"""Random Image / CameraInfo field combinations: only our own documented error type ever escapes.

A node survives anything that raises StereoDepthError (it logs, skips the frame, goes on); anything
else is a bug, and a crash inside OpenCV takes the whole process down. So these throw field
combinations no driver should send (but some do) at every layer a message goes through.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereo_depth.bag.types import rosbags_types
from stereo_depth.core.camera import DISTORTION_MODELS, StereoCamera
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import StereoDepthError
from stereo_depth.messages import CAMERA_ENCODINGS, ENCODINGS, camera_info_from_msg, image_to_pipeline, make_header

T = rosbags_types()
HEADER = make_header(T, 1, "cam")
MAX_PIXELS = 20_000
# derandomize: the same examples on every run and machine, so a failure reproduces and CI cannot flake
EXAMPLES = settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
JUNK_ENCODINGS = ["", "yuv422", "yuv422_yuy2", "nv21", "32FC1", "16SC1", "64FC1", "jpeg", "png", "mono8 ", "MONO8"]
UINT32_EDGES = [2**16, 2**31 - 1, 2**31, 2**32 - 1]


def uint32(small: int) -> st.SearchStrategy[int]:
    """Mostly small, sometimes the values that overflow someone's arithmetic."""
    return st.one_of(st.integers(0, small), st.sampled_from(UINT32_EDGES))


@st.composite
def images(draw: st.DrawFn, size: tuple[int, int] | None = None, plausible_odds: float = 0.5) -> Any:
    """Any Image, about `plausible_odds` of them plausible (mostly decodable); `size` (height, width)
    makes it the partner of one that was."""
    plausible = draw(st.integers(0, 99)) < round(100 * plausible_odds)
    camera = st.sampled_from(sorted(CAMERA_ENCODINGS))
    known = st.sampled_from(sorted(ENCODINGS))
    encoding = draw(camera if plausible else st.one_of(known, st.sampled_from(JUNK_ENCODINGS), st.text(max_size=6)))
    if size is None:
        heights, widths = (st.integers(1, 40), st.integers(1, 120)) if plausible else (uint32(40), uint32(120))
        size = (draw(heights), draw(widths))
    height, width = size
    dtype, channels, _ = ENCODINGS.get(encoding, ("u1", 1, None))
    row = width * channels * np.dtype(dtype).itemsize
    itemsize = np.dtype(dtype).itemsize
    padding = st.integers(0, 8 // itemsize).map(lambda n: n * itemsize)
    step = draw(padding.map(lambda pad: row + pad) if plausible else st.one_of(st.just(row), uint32(400)))
    consistent = step * height <= 200_000 and (plausible or draw(st.booleans()))
    size_bytes = step * height if consistent else draw(st.integers(0, 2_000))
    data = draw(st.binary(min_size=size_bytes, max_size=size_bytes))
    return T.Image(
        header=HEADER,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=draw(st.integers(0, 1) if plausible else st.integers(0, 255)),
        step=step,
        data=np.frombuffer(data, np.uint8) if data else np.zeros(0, np.uint8),
    )


ODD_FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, np.nan, np.inf, -np.inf]),
)


def perturbed(base: list[float]) -> st.SearchStrategy[list[float]]:
    """A plausible matrix with a few entries replaced, or of a wrong length now and then."""
    edits = st.lists(st.tuples(st.integers(0, len(base) - 1), ODD_FLOATS), max_size=3)

    def apply(changes: list[tuple[int, float]]) -> list[float]:
        values = list(base)
        for index, value in changes:
            values[index] = value
        return values

    return st.one_of(edits.map(apply), st.lists(ODD_FLOATS, max_size=13))


@st.composite
def camera_infos(draw: st.DrawFn, width: int, height: int, tx: float) -> Any:
    fx = draw(st.sampled_from([40.0, 100.0, 1e-3, 1e6]))
    k = [fx, 0.0, width / 2, 0.0, fx, height / 2, 0.0, 0.0, 1.0]
    p = [fx, 0.0, width / 2, -fx * tx, 0.0, fx, height / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
    r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    d = draw(st.one_of(st.lists(st.floats(-0.5, 0.5), max_size=15), st.lists(ODD_FLOATS, max_size=15)))
    return T.CameraInfo(
        header=HEADER,
        height=draw(st.one_of(st.just(height), uint32(100))),
        width=draw(st.one_of(st.just(width), uint32(200))),
        distortion_model=draw(st.sampled_from([*DISTORTION_MODELS, "", "fancy"])),
        d=np.asarray(d, np.float64),
        k=np.asarray(draw(perturbed(k)), np.float64),
        r=np.asarray(draw(perturbed(r)), np.float64),
        p=np.asarray(draw(perturbed(p)), np.float64),
        binning_x=0,
        binning_y=0,
        roi=T.RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def only_our_errors(call: Any, *args: Any, **kwargs: Any) -> Any:
    """The call's result, or None when it refused with a StereoDepthError that explains itself."""
    try:
        return call(*args, **kwargs)
    except StereoDepthError as exc:
        assert str(exc), "an error without a message"
        return None


@EXAMPLES
@given(images())
def test_image_conversion_raises_only_image_errors(msg: Any) -> None:
    pixels = only_our_errors(image_to_pipeline, msg, max_pixels=MAX_PIXELS)
    if pixels is not None:
        assert pixels.shape[:2] == (msg.height, msg.width)
        assert pixels.dtype in (np.uint8, np.uint16) and (pixels.ndim == 2 or pixels.shape[2] == 3)


@EXAMPLES
@given(st.data())
def test_calibrations_raise_only_calibration_errors(data: st.DataObject) -> None:
    width, height = data.draw(st.integers(1, 160)), data.draw(st.integers(1, 60))
    left_msg = data.draw(camera_infos(width, height, 0.0))
    right_msg = data.draw(camera_infos(width, height, data.draw(st.sampled_from([0.1, 0.0, -0.1, 1e9]))))
    left, right = only_our_errors(camera_info_from_msg, left_msg), only_our_errors(camera_info_from_msg, right_msg)
    if left is None or right is None:
        return
    camera = only_our_errors(StereoCamera, left, right)
    if camera is None:
        return
    image = np.zeros((height, width), np.uint8)
    for side in ("left", "right"):
        only_our_errors(camera.rectify, image, side)


@pytest.fixture(scope="module")
def pipelines() -> dict[str, StereoPipeline]:
    return {
        name: StereoPipeline(make_params("default", {"matcher": name, "disparity_range": 16}))
        for name in ("bm", "sgbm", "census_sgm")
    }


def test_pipeline_raises_only_our_errors_for_any_decoded_pair(pipelines: dict[str, StereoPipeline]) -> None:
    """Mostly plausible pairs, so that most examples get as far as `StereoPipeline.process` (counted)."""
    reached = {"examples": 0, "pipeline": 0}

    @EXAMPLES
    @given(st.data())
    def check(data: st.DataObject) -> None:
        reached["examples"] += 1
        left = only_our_errors(image_to_pipeline, data.draw(images(plausible_odds=0.95)), max_pixels=MAX_PIXELS)
        if left is None:
            return
        height, width = left.shape[:2]
        same_size = data.draw(st.sampled_from([True, True, True, False]))
        right_msg = data.draw(images((height, width) if same_size else None, plausible_odds=0.95))
        right = only_our_errors(image_to_pipeline, right_msg, max_pixels=MAX_PIXELS)
        if right is None:
            return
        infos = [only_our_errors(camera_info_from_msg, data.draw(camera_infos(width, height, tx))) for tx in (0.0, 0.1)]
        camera = None if None in infos else only_our_errors(StereoCamera, *infos)
        pipeline = pipelines[data.draw(st.sampled_from(sorted(pipelines)))]
        rectified = camera is None or data.draw(st.booleans())
        reached["pipeline"] += 1
        result = only_our_errors(pipeline.process, left, right, camera, rectified=rectified)
        if result is not None:
            assert result.disparity.shape == (height, width) and result.disparity.dtype == np.float32

    check()
    assert reached["pipeline"] >= 0.75 * reached["examples"], reached
