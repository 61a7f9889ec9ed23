"""Message <-> array conversions: every stereo camera encoding, row padding, byte order, cloud layout.

Messages are built as rosbags messages and sent through real CDR serialization, so the bytes are
those a Jazzy publisher puts on the wire.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from stereo_depth.bag.types import deserialize, rosbags_types, serialize
from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.geometry import Rays, depth_to_points, disparity_to_depth
from stereo_depth.errors import ImageError
from stereo_depth.formats.scenes import load_scene
from stereo_depth.messages import (
    MessageBuffer,
    SerializedMessage,
    array_to_image,
    camera_info_from_msg,
    camera_info_to_msg,
    cloud_to_arrays,
    depth_to_cloud,
    disparity_from_msg,
    disparity_to_msg,
    image_to_array,
    image_to_pipeline,
    make_header,
)

from conftest import SCENES

T = rosbags_types()
HEADER = make_header(T, 1_700_000_000_123_456_789, "cam_left")


def wire(message: object) -> object:
    return deserialize(serialize(message), message.__msgtype__)  # type: ignore[attr-defined]


def raw_image(encoding: str, height: int, width: int, step: int, data: bytes, bigendian: bool = False) -> object:
    return T.Image(
        header=HEADER,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=step,
        data=np.frombuffer(data, np.uint8),
    )


@pytest.fixture(scope="module")
def bgr() -> np.ndarray:
    return load_scene(SCENES / "artl").left


def test_image_round_trip_keeps_pixels_and_header(bgr: np.ndarray) -> None:
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    for pixels in (
        grey,
        bgr,
        grey.astype(np.uint16) * 257,
        np.linspace(0, 1, grey.size, dtype=np.float32).reshape(grey.shape),
    ):
        msg = wire(array_to_image(T, HEADER, pixels))
        assert msg.header.frame_id == "cam_left" and msg.header.stamp.nanosec == 123_456_789  # type: ignore[attr-defined]
        np.testing.assert_array_equal(image_to_array(msg), pixels)


@pytest.mark.parametrize(
    ("encoding", "convert"),
    [
        ("rgb8", cv2.COLOR_BGR2RGB),
        ("rgba8", cv2.COLOR_BGR2RGBA),
        ("bgra8", cv2.COLOR_BGR2BGRA),
    ],
)
def test_colour_encodings_arrive_as_bgr(bgr: np.ndarray, encoding: str, convert: int) -> None:
    pixels = cv2.cvtColor(bgr, convert)
    height, width, channels = pixels.shape
    msg = raw_image(encoding, height, width, width * channels, pixels.tobytes())
    np.testing.assert_array_equal(image_to_pipeline(msg), bgr)


def test_bayer_rggb_is_debayered_to_the_right_colours() -> None:
    # a flat orange scene seen through an RGGB mosaic: R=200, G=100, B=20
    mosaic = np.zeros((8, 8), np.uint8)
    mosaic[0::2, 0::2], mosaic[0::2, 1::2], mosaic[1::2, 0::2], mosaic[1::2, 1::2] = 200, 100, 100, 20
    out = image_to_pipeline(raw_image("bayer_rggb8", 8, 8, 8, mosaic.tobytes()))
    b, g, r = out[4, 4]
    assert (abs(int(r) - 200), abs(int(g) - 100), abs(int(b) - 20)) <= (5, 5, 5)


def test_padded_rows_and_big_endian_16_bit_are_read_correctly() -> None:
    values = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    rows = [values[r].astype(">u2").tobytes() + b"\xee" * 6 for r in range(3)]  # 8 data bytes + 6 padding
    msg = raw_image("mono16", 3, 4, 14, b"".join(rows), bigendian=True)
    np.testing.assert_array_equal(image_to_array(msg), values)


@pytest.mark.parametrize(
    ("msg", "reason"),
    [
        (raw_image("yuv422", 2, 2, 4, bytes(8)), "'yuv422' is not supported"),
        (raw_image("32FC1", 2, 2, 8, bytes(16)), "'32FC1' is not supported"),
        (raw_image("", 2, 2, 2, bytes(4)), "empty encoding"),
        (raw_image("mono8", 2, 2, 1, bytes(2)), "smaller than one row"),
        (raw_image("mono8", 2, 2, 2, bytes(3)), "3 bytes but step x height"),
        (raw_image("mono8", 0, 0, 0, b""), "zero-sized"),
    ],
)
def test_undecodable_images_are_refused_by_name(msg: object, reason: str) -> None:
    with pytest.raises(ImageError, match=reason):
        image_to_pipeline(msg)


def test_image_larger_than_the_limit_is_refused_before_reading_it() -> None:
    with pytest.raises(ImageError, match="limit"):
        image_to_array(raw_image("mono8", 100, 100, 100, bytes(10_000)), max_pixels=5_000)


def test_camera_info_round_trip() -> None:
    left, _ = load_scene(SCENES / "artl").camera_infos()
    back = camera_info_from_msg(wire(camera_info_to_msg(T, HEADER, left)))
    assert back == left


@pytest.fixture(scope="module")
def camera() -> StereoCamera:
    return StereoCamera(*load_scene(SCENES / "artl").camera_infos())


def test_disparity_message_is_offset_adjusted_like_stereo_image_proc(camera: StereoCamera) -> None:
    disparity = np.array([[20.0, np.nan], [30.5, 16.0]], np.float32)
    msg = wire(disparity_to_msg(T, HEADER, disparity, camera, 16, 64, (0, 0, 2, 2)))
    offset = camera.disparity_offset  # cx_l - cx_r = -doffs = -50
    assert msg.f == camera.fx and msg.t == pytest.approx(0.160)  # type: ignore[attr-defined]
    assert msg.min_disparity == pytest.approx(16 - offset)  # type: ignore[attr-defined]
    assert msg.max_disparity == pytest.approx(16 - offset + 63)  # type: ignore[attr-defined]
    image = image_to_array(msg.image)  # type: ignore[attr-defined]
    assert image[0, 0] == pytest.approx(20.0 - offset)
    assert image[0, 1] < msg.min_disparity  # type: ignore[attr-defined]
    back = disparity_from_msg(msg)
    assert back[1, 1] == pytest.approx(16.0 - offset)  # a valid point at the minimum disparity is kept
    # Z = f * t / d' with no further offset gives the calibrated depth
    assert msg.f * msg.t / back[0, 0] == pytest.approx(0.160 * 935.0 / (20.0 + 50.0))  # type: ignore[attr-defined]


def test_disparity_message_of_a_camera_without_offset_holds_the_disparity_itself(camera: StereoCamera) -> None:
    """cx_l = cx_r, as most drivers' rectified calibrations have it (its pixels take one pass, not two):
    valid pixels are the disparity, invalid ones (NaN) min_disparity - 1, as with an offset."""
    left, right = load_scene(SCENES / "artl").camera_infos()
    p = right.p.copy()
    p[0, 2] = left.p[0, 2]
    aligned = StereoCamera(left, dataclasses.replace(right, p=p))
    assert aligned.disparity_offset == 0.0 and camera.disparity_offset != 0.0
    disparity = np.array([[20.0, np.nan], [30.5, 16.0]], np.float32)
    for stereo in (aligned, camera):
        msg = wire(disparity_to_msg(T, HEADER, disparity, stereo, 16, 64, (0, 0, 2, 2)))
        offset = np.float32(stereo.disparity_offset)
        image = image_to_array(msg.image)  # type: ignore[attr-defined]
        assert msg.min_disparity == 16 - offset  # type: ignore[attr-defined]
        expected = np.where(np.isnan(disparity), np.float32(16 - offset - 1), disparity - offset)
        np.testing.assert_array_equal(image, expected)


def test_disparity_in_a_reused_buffer_is_the_disparity_in_a_fresh_one(camera: StereoCamera) -> None:
    """Nodes and `process` compute the DisparityImage's pixels straight into a buffer reused frame after
    frame: each message must serialize as one built fresh, invalid pixels included."""
    scene = load_scene(SCENES / "artl")
    assert scene.gt is not None
    buffer = MessageBuffer()
    for disparity in (scene.gt, scene.gt[:, ::-1].copy()):  # the second frame reuses the buffer
        assert np.isnan(disparity).any()
        args = (T, HEADER, disparity, camera, 0, 64, (0, 0, 1, 1))
        fresh = serialize(disparity_to_msg(*args))
        assert bytes(serialize(disparity_to_msg(*args, buffer=buffer))) == bytes(fresh)


def test_disparity_without_encoding_reads_as_32fc1_when_it_fits(camera: StereoCamera) -> None:
    """stereo_image_proc reads a DisparityImage as float whatever its encoding; its point cloud test fixture
    sets none. Bytes that fit 4-byte pixels read as 32FC1; others are refused with the fix, never guessed."""
    disparity = np.array([[20.0, np.nan], [30.5, 16.0]], np.float32)
    msg = disparity_to_msg(T, HEADER, disparity, camera, 16, 64, (0, 0, 2, 2))
    expected = disparity_from_msg(msg)
    msg.image.encoding = ""
    np.testing.assert_array_equal(disparity_from_msg(msg), expected)
    # upstream's fixture: float64 pixels under a float32 step (2x the data that step x height says)
    msg.image.data = np.nan_to_num(disparity).astype(np.float64).tobytes()
    with pytest.raises(ImageError, match=r"empty encoding and does not fit 32FC1.*publish it as 32FC1"):
        disparity_from_msg(msg)
    msg.image.encoding = "rgb9"
    with pytest.raises(ImageError, match="a DisparityImage holds 32FC1"):
        disparity_from_msg(msg)


@pytest.mark.parametrize(("avoid_padding", "offsets", "step"), [(False, [0, 4, 8, 16], 32), (True, [0, 4, 8, 12], 16)])
def test_cloud_layout_matches_stereo_image_proc(
    camera: StereoCamera, avoid_padding: bool, offsets: list[int], step: int
) -> None:
    depth = (1.0 + np.random.default_rng(0).random((3, 4))).astype(np.float32)
    depth[1, 2] = np.nan
    rays = Rays(x=np.linspace(-0.5, 0.5, 4, dtype=np.float32)[None, :], y=np.array([[-0.2], [0.0], [0.3]], np.float32))
    color = np.zeros((3, 4, 3), np.uint8)
    color[0, 0] = (0, 0, 255)  # BGR red
    msg = wire(depth_to_cloud(T, HEADER, depth, rays, color, avoid_padding))
    assert [f.offset for f in msg.fields] == offsets and msg.point_step == step  # type: ignore[attr-defined]
    assert (msg.height, msg.width, msg.is_dense) == (3, 4, False)  # type: ignore[attr-defined]
    xyz, rgb = cloud_to_arrays(msg)
    np.testing.assert_array_equal(xyz, depth_to_points(depth, rays))
    assert np.isnan(xyz[1, 2]).all() and xyz[2, 1, 1] == np.float32(0.3) * depth[2, 1]
    assert rgb is not None and rgb[0, 0] == 0x00FF0000
    records = np.frombuffer(bytes(msg.data), np.uint8).reshape(-1, step)  # type: ignore[attr-defined]
    padding = np.ones(step, bool)
    for offset in offsets:
        padding[offset : offset + 4] = False
    assert not records[:, padding].any()  # the bytes between the fields are zero


@pytest.mark.parametrize("avoid_padding", [False, True])
@pytest.mark.parametrize("grey", [False, True])
def test_cloud_in_a_reused_buffer_is_the_cloud_in_a_fresh_one_byte_for_byte(
    camera: StereoCamera, avoid_padding: bool, grey: bool
) -> None:
    """Nodes and `process` write x, y, z straight into a buffer reused frame after frame: it must give
    the bytes a fresh buffer gives, NaN patterns and untouched padding included."""
    scene = load_scene(SCENES / "artl")
    color = cv2.cvtColor(scene.left, cv2.COLOR_BGR2GRAY) if grey else scene.left
    rays = Rays.for_camera(camera)
    buffer = MessageBuffer()
    assert scene.gt is not None
    for disparity in (scene.gt, scene.gt[:, ::-1].copy()):  # the second frame reuses the buffer
        depth = disparity_to_depth(disparity, camera)
        expected = wire(depth_to_cloud(T, HEADER, depth, rays, color, avoid_padding))
        in_place = wire(depth_to_cloud(T, HEADER, depth, rays, color, avoid_padding, buffer))
        assert bytes(in_place.data) == bytes(expected.data)  # type: ignore[attr-defined]
        np.testing.assert_array_equal(cloud_to_arrays(in_place)[0], depth_to_points(depth, rays))
        assert np.isnan(cloud_to_arrays(in_place)[0]).any()  # invalid pixels are NaN, not zeros


@pytest.mark.parametrize("avoid_padding", [False, True])
def test_disparity_and_cloud_built_in_their_cdr_bytes_are_what_rclpy_serializes(
    camera: StereoCamera, avoid_padding: bool
) -> None:
    """The live nodes build the disparity and an organized points2 straight into their serialized bytes
    (published with the GIL released): the bytes must be a whole message, the same one rclpy would
    serialize, frame after frame in one reused buffer, a longer frame_id included."""
    from rclpy.serialization import deserialize_message, serialize_message

    from stereo_depth.ros.types import RCLPY_SERIALIZED, RCLPY_TYPES

    scene = load_scene(SCENES / "artl")
    rays = Rays.for_camera(camera)
    buffer, disparity_buffer = MessageBuffer(), MessageBuffer()
    assert scene.gt is not None
    for frame_id, disparity in (("cam", scene.gt), ("camera_left_optical", scene.gt[:, ::-1].copy())):
        header = make_header(RCLPY_TYPES, 1_700_000_000_123_456_789, frame_id)
        depth = disparity_to_depth(disparity, camera)
        built = depth_to_cloud(RCLPY_SERIALIZED, header, depth, rays, scene.left, avoid_padding, buffer)
        assert isinstance(built, SerializedMessage) and built.msg_type is RCLPY_TYPES.PointCloud2
        expected = depth_to_cloud(RCLPY_TYPES, header, depth, rays, scene.left, avoid_padding)
        assert built.buffer.nbytes == len(serialize_message(expected))
        received = deserialize_message(built.buffer.tobytes(), RCLPY_TYPES.PointCloud2)
        assert received == expected  # every field, the header and all the points' bytes
        np.testing.assert_array_equal(cloud_to_arrays(received)[0], depth_to_points(depth, rays))
        window = (3, 1, 100, 200)
        built = disparity_to_msg(RCLPY_SERIALIZED, header, disparity, camera, 4, 64, window, buffer=disparity_buffer)
        assert isinstance(built, SerializedMessage) and built.msg_type is RCLPY_TYPES.DisparityImage
        expected = disparity_to_msg(RCLPY_TYPES, header, disparity, camera, 4, 64, window)
        received = deserialize_message(built.buffer.tobytes(), RCLPY_TYPES.DisparityImage)
        round_trip = deserialize_message(serialize_message(expected), RCLPY_TYPES.DisparityImage)  # float32 t
        assert received == round_trip  # the fields after the image's data too (the data's length is odd x 4)
