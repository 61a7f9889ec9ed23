"""Glare (invalidate_saturated): no disparity, depth or point from a saturated, textureless area of either
image, none refilled, and none judged on a 16-bit frame's own peak. The bundled EuRoC bag and pairs hold
a bright window of the Vicon room (about a tenth of each frame)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from stereo_depth.bag.reader import StereoBagReader
from stereo_depth.bag.types import rosbags_types
from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.core.saturation import rectified_glare, seen_in_right
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.frames import FrameStream
from stereo_depth.messages import cloud_to_arrays, disparity_from_msg, image_to_array
from stereo_depth.options import OutputOptions

from conftest import read_image

DATA = Path(__file__).resolve().parent / "data" / "euroc"
EUROC_BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"
OUTPUTS = ("disparity", "depth", "points2", "points2_clearing")


def euroc_pair() -> tuple[np.ndarray, np.ndarray, StereoCamera]:
    name = sorted((DATA / "left").glob("*.png"))[0].name
    left, right = (read_image(DATA / side / name, cv2.IMREAD_GRAYSCALE) for side in ("left", "right"))
    return left, right, StereoCamera(*stereo_camera_infos(DATA / "cam0_sensor.yaml", DATA / "cam1_sensor.yaml"))


def matched(left: np.ndarray, right: np.ndarray, camera: StereoCamera, **overrides: object) -> StereoResult:
    return StereoPipeline(make_params("default", dict(overrides))).match(left, right, camera)


def frame_outputs(**overrides: object) -> tuple[StereoResult, dict[str, np.ndarray]]:
    """The first bag frame's glare result and its outputs as per-pixel arrays: disparity, depth, the organized
    points2's z, and a mask of the pixels points2_clearing has a point for."""
    output = OutputOptions(clearing_max_depth=10.0)
    with StereoBagReader(EUROC_BAG) as reader:
        stream = FrameStream(
            rosbags_types(), make_params("default", dict(overrides)), output, names=reader.topics.input_names
        )
        out = stream.match(next(iter(reader.frames())), OUTPUTS)
    assert out.cloud is not None
    messages = {**out.images, **out.cloud.run().messages}
    depth = image_to_array(messages["depth"])
    xyz = cloud_to_arrays(messages["points2_clearing"])[0].reshape(-1, 3).astype(np.float64)
    camera = out.result.camera
    assert camera is not None
    columns = np.rint(camera.fx * xyz[:, 0] / xyz[:, 2] + camera.cx_left).astype(int)
    rows = np.rint(camera.fy * xyz[:, 1] / xyz[:, 2] + camera.cy).astype(int)
    clearing = np.zeros(depth.shape, bool)
    clearing[rows, columns] = True
    arrays = {
        "disparity": disparity_from_msg(messages["disparity"]),
        "depth": depth,
        "points2": cloud_to_arrays(messages["points2"])[0][:, :, 2],
        "points2_clearing": clearing,
    }
    return out.result, arrays


def test_glare_gives_no_disparity_depth_point_or_clearing_ray() -> None:
    """Off, SGBM matches most of the window (at the smallest disparity: a clearing ray each); on, none of it
    reaches any output, and the rest of the frame keeps its disparities."""
    _, off = frame_outputs(invalidate_saturated=False)
    result, on = frame_outputs(invalidate_saturated=True, fill_holes=True)
    glare = result.glare
    assert glare is not None and glare.mean() > 0.05
    assert np.isfinite(off["disparity"][glare]).mean() > 0.3
    assert np.isfinite(off["points2"][glare]).mean() > 0.3
    for name in ("disparity", "depth", "points2"):
        assert not np.isfinite(on[name][glare]).any(), name
    assert not on["points2_clearing"][glare].any()
    assert np.isfinite(on["disparity"][~glare]).mean() > 0.95  # hole filling still fills everything else


def test_glare_seen_through_the_right_image_is_invalid_too() -> None:
    """A left pixel whose match lies in the right image's glare has no disparity either."""
    left, right, camera = euroc_pair()
    off = matched(left, right, camera, invalidate_saturated=False)
    on = matched(left, right, camera, invalidate_saturated=True)
    right_glare = rectified_glare(right, None, camera, "right", left.shape, 0)
    assert right_glare is not None and off.glare is not None
    seen = seen_in_right(off.disparity, right_glare) & ~off.glare
    assert seen.sum() > 300  # the window frame seen through the right glare
    assert not np.isfinite(on.disparity[seen]).any()
    untouched = ~seen & ~off.glare
    np.testing.assert_array_equal(on.disparity[untouched], off.disparity[untouched])


def test_hole_filling_leaves_glare_empty() -> None:
    left, right, camera = euroc_pair()
    result = matched(left, right, camera, fill_holes=True, invalidate_saturated=True)
    assert result.glare is not None
    assert not np.isfinite(result.disparity[result.glare]).any()
    assert np.isfinite(result.disparity[~result.glare]).mean() > 0.95


def twelve_bit(image: np.ndarray, gain: float) -> np.ndarray:
    """The 8-bit image as a 12-bit sensor in a 16-bit container would give it: `gain` x 16 per level,
    clipped at the sensor's full scale 4095 (the glare saturates there, as it does in the 8-bit image)."""
    raw = image.astype(np.float32) * np.float32(16 * gain)
    raw[image == 255] = 4095
    clipped: np.ndarray = np.clip(raw, 0, 4095).astype(np.uint16)
    return clipped


def test_a_12_bit_sensor_saturates_at_4095_not_at_its_container_maximum() -> None:
    left, right, camera = euroc_pair()
    eight_bit = matched(left, right, camera)
    wide_left, wide_right = (twelve_bit(image, 1.0) for image in (left, right))
    judged = matched(wide_left, wide_right, camera, saturation_level=4095)
    assert eight_bit.glare is not None and judged.glare is not None
    overlap = (judged.glare & eight_bit.glare).sum() / (judged.glare | eight_bit.glare).sum()
    assert overlap > 0.97  # the same window (rectification rounds 12-bit values finer than 8-bit ones)
    assert not np.isfinite(judged.disparity[judged.glare]).any()
    assert matched(wide_left, wide_right, camera).glare is None  # 4095 is far below 65535: nothing saturates


@pytest.mark.parametrize("gain", [0.5, 0.9])
def test_a_dim_16_bit_frame_has_no_glare_although_its_peak_becomes_white(gain: float) -> None:
    """A frame whose brightest pixel is below the sensor's full scale holds no glare, although the matcher's
    8-bit image maps that peak to 255: saturation is judged on the raw values."""
    left, right, camera = euroc_pair()
    dim_left, dim_right = (np.minimum(twelve_bit(image, 1.0), np.uint16(4095 * gain)) for image in (left, right))
    result = matched(dim_left, dim_right, camera, saturation_level=4095)
    assert (result.left_rect == 255).mean() > 0.05  # the clipped window is white in the 8-bit image
    assert result.glare is None
    off = matched(dim_left, dim_right, camera, saturation_level=4095, invalidate_saturated=False)
    np.testing.assert_array_equal(result.disparity, off.disparity)
