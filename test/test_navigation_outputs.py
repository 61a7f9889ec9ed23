"""What costmaps read besides depth and points2: `points2_clearing` (free space out to the far pixels)
and `depth/compressedDepth` (image_transport's compressedDepth), from stereo_node over real DDS on the
raw EuRoC pair and from `stereo-depth process` on the bundled bag.

The compressedDepth messages are decoded here by the documented layout alone (compressed_depth_image_
transport's codec.cpp and rvl_codec.cpp): format "<encoding>; compressedDepth <png|rvl>", a 12-byte
ConfigHeader (int32 compressionFormat, float32 depthParam[2]), then PNG, or RVL (uint32 width, uint32
height, then 4-bit groups in little-endian int32 words, the first group in the top bits), with the
checks by which that decoder drops a message, so a frame image_transport's own subscriber would drop
fails here too.
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from compressed_depth import mostly_invalid  # bench/ (on the path by conftest): the frames RVL packs tightest
from diagnostic_msgs.msg import DiagnosticArray
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from stereo_msgs.msg import DisparityImage
from test_nodes import Pair, StereoInput, euroc_pair, send_with_parameters, wait_until_delivered

from stereo_depth.bag.reader import read_messages
from stereo_depth.cli import main
from stereo_depth.core.rvl import rvl_compress
from stereo_depth.core.saturation import glare_area, saturated
from stereo_depth.frames import depth_pixels
from stereo_depth.messages import (
    COMPRESSED_DEPTH_FORMATS,
    RVL_FALLBACK_NOTE,
    array_to_image,
    cloud_to_arrays,
    compressed_depth_codec,
    depth_to_compressed_depth,
    disparity_from_msg,
    image_to_array,
    make_header,
)
from stereo_depth.ros.types import RCLPY_TYPES

NS = "/clear"
BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"
OUTPUTS = {
    "disparity": DisparityImage,
    "depth": Image,
    "depth/camera_info": CameraInfo,
    "depth/compressedDepth": CompressedImage,
    "points2": PointCloud2,
    "points2_clearing": PointCloud2,
    "left/image_rect": Image,
}
_stamps = itertools.count(1_900_000_000 * 10**9, 250_000_000)


# ---------------------------------------------------------------- a decoder written from the format


def rvl_decode(data: bytes, pixels: int) -> np.ndarray:
    """RVL: per run the count of zeros, the count of nonzeros, then each nonzero as the zigzag delta to
    the previous nonzero; each value in 3-bit groups, low group first, bit 3 set while more follow."""
    words = np.frombuffer(data, "<u4")
    nibbles = ((words[:, None] >> np.arange(28, -1, -4, dtype=np.uint32)) & 0xF).ravel().astype(np.int64)
    last = (nibbles & 8) == 0  # the last group of a value
    value_of = np.concatenate([[0], np.cumsum(last)[:-1]])
    first = np.concatenate([[0], np.flatnonzero(last)[:-1] + 1])
    shift = 3 * (np.arange(nibbles.size) - first[value_of])
    values = np.bincount(value_of, weights=(nibbles & 7) << shift).astype(np.int64)[: int(last.sum())]
    out, at, previous, i = np.zeros(pixels, np.int64), 0, 0, 0
    while at < pixels:
        zeros, nonzeros = int(values[i]), int(values[i + 1])
        zigzag = values[i + 2 : i + 2 + nonzeros]
        deltas = (zigzag >> 1) ^ -(zigzag & 1)
        at += zeros
        out[at : at + nonzeros] = previous + np.cumsum(deltas)
        previous = int(out[at + nonzeros - 1]) if nonzeros else previous
        at, i = at + nonzeros, i + 2 + nonzeros
    return out.astype(np.uint16)


BIT_DEPTHS = {"16UC1": 16, "32FC1": 32}  # sensor_msgs::image_encodings::bitDepth, the two codec.cpp takes


def format_as_read(format_: str) -> tuple[str, str]:
    """(encoding, codec) as codec.cpp's decodeCompressedDepthImage reads the format string: the encoding
    before the first ';', the codec from "compressedDepth png|rvl" after it (png when only
    "compressedDepth" or no ';' at all, as older publishers wrote); anything else it drops."""
    encoding, semicolon, ending = format_.partition(";")
    if not semicolon or "compressedDepth png" in ending:
        return encoding, "png"
    if "compressedDepth rvl" in ending:
        return encoding, "rvl"
    assert "compressedDepth" in ending and "compressedDepth " not in ending, f"unsupported format: {format_}"
    return encoding, "png"


def decode_compressed_depth(msg: Any) -> tuple[np.ndarray, str, str]:
    """(depth as the subscriber gives it, encoding, codec): 32FC1 metres (NaN invalid) or 16UC1 mm.

    Fails where codec.cpp (Jazzy) returns no image: data no longer than the ConfigHeader; an RVL size
    with a zero; an RVL stream (size included) of fewer bytes than pixels / 5, which it takes for a
    corrupt one ("malformed RVL-encoded image"). That last check guards only its 32FC1 path; a stricter
    decoder may apply it to 16UC1, so here it holds for both."""
    encoding, codec = format_as_read(str(msg.format))
    assert encoding in BIT_DEPTHS, f"codec.cpp decodes 16- and 32-bit depth, not {encoding}"
    data = bytes(msg.data)
    assert len(data) > 12, "no image after the ConfigHeader"
    compression_format, quant_a, quant_b = struct.unpack("<iff", data[:12])
    assert compression_format == 0  # INV_DEPTH
    image_data = data[12:]
    pixels: np.ndarray | None
    if codec == "rvl":
        width, height = struct.unpack("<II", image_data[:8])
        assert width and height, f"malformed RVL-encoded image: size {width}x{height} contains zero"
        count = width * height
        assert count <= min(2**31 - 1, len(image_data) * 5), (
            f"malformed RVL-encoded image: {count} pixels from {len(image_data)} bytes"
        )
        pixels = rvl_decode(image_data[8:], count).reshape(height, width)
    else:
        pixels = cv2.imdecode(np.frombuffer(image_data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert pixels is not None and pixels.dtype == np.uint16 and pixels.ndim == 2
    if encoding == "16UC1":
        return pixels, encoding, codec
    with np.errstate(divide="ignore"):
        depth = np.float32(quant_a) / (pixels.astype(np.float32) - np.float32(quant_b))
    depth[pixels == 0] = np.nan
    return depth, encoding, codec


def assert_decodes_to_depth(
    compressed: Any, depth_msg: Any, depth_max: float = 10.0, z0: float = 100.0, min_valid: float = 0.0
) -> None:
    """`compressed` passes the standard decoder's checks and gives `depth_msg`'s depth: exactly for 16UC1,
    within one step of the 16-bit inverse depth for 32FC1; `min_valid`: the share of depth it must keep."""
    decoded, encoding, _ = decode_compressed_depth(compressed)
    depth = image_to_array(depth_msg)
    assert encoding == depth_msg.encoding and decoded.shape == depth.shape
    if encoding == "16UC1":  # lossless, but nothing beyond depth_max (the plugin's rule)
        expected = np.where(depth > depth_max * 1000, 0, depth)
        np.testing.assert_array_equal(decoded, expected)
        assert (expected > 0).mean() >= min_valid
        return
    kept = depth < depth_max  # NaN and depth_max and beyond: invalid after the round trip
    np.testing.assert_array_equal(np.isfinite(decoded), kept)
    assert kept.mean() >= min_valid
    # 16-bit inverse depth q = A / z + B, truncated: the decoded depth is never nearer, and its inverse
    # is off by less than one step 1 / A (A = z0 (z0 + 1)); 1e-6 of float32 rounding on top
    a = z0 * (z0 + 1)
    z, back = depth[kept].astype(np.float64), decoded[kept].astype(np.float64)
    assert np.all(back >= z * (1 - 1e-6))
    assert np.all(1 / z - 1 / back < 1 / a + 1e-6 / z)


def test_rvl_words_are_the_documented_groups_in_order() -> None:
    # values: 2 zeros, 2 nonzeros, zigzag(5 - 0) = 10, zigzag(7 - 5) = 4, 1 zero, 0 nonzeros;
    # groups: 2 | 2 | 10 = 0b1_010 -> 0xA (2, more follow), 0x1 | 4 | 1 | 0; the word filled from the top
    # and zero-filled: 0x22A14100, stored little-endian
    assert rvl_compress(np.array([[0, 0, 5, 7, 0]], np.uint16)).tobytes() == bytes.fromhex("0041a122")
    ramp = np.arange(1, 41, dtype=np.uint16).reshape(5, 8)  # no zero run first: an empty one is written
    np.testing.assert_array_equal(rvl_decode(rvl_compress(ramp).tobytes(), ramp.size), ramp.ravel())


def depth_frames() -> dict[str, np.ndarray]:
    """32FC1 depth at EuRoC's size, from the frames RVL packs tightest (the bench's: a floor valid only
    in its nearest rows) to a typical one: a wall at 4 m with a matcher's noise and holes."""
    rng = np.random.default_rng(0)
    wall = np.float32(4.0) + rng.normal(0.0, 0.02, (480, 752)).astype(np.float32)
    wall[cv2.resize(rng.random((12, 19)), (752, 480), interpolation=cv2.INTER_NEAREST) < 0.2] = np.nan
    return {**mostly_invalid(wall.shape), "typical": wall}


@pytest.mark.parametrize("codec", COMPRESSED_DEPTH_FORMATS)
@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_every_compressed_depth_frame_passes_the_standard_decoders_checks(encoding: str, codec: str) -> None:
    """RVL packs runs of invalid pixels far tighter than image_transport's decoder believes RVL can (5
    pixels a byte): it drops such a 32FC1 frame as corrupt. With rvl asked for, those frames go as PNG."""
    header = make_header(RCLPY_TYPES, 1, "cam0")
    for name, depth in depth_frames().items():
        pixels = depth_pixels(depth, encoding)
        compressed = depth_to_compressed_depth(RCLPY_TYPES, header, pixels, encoding, codec=codec)
        assert_decodes_to_depth(compressed, array_to_image(RCLPY_TYPES, header, pixels, encoding))
        if codec == "rvl" and name in ("all invalid", "typical"):
            assert compressed_depth_codec(compressed) == ("png" if name == "all invalid" else "rvl"), name


# ---------------------------------------------------------------- live


@pytest.fixture(scope="module")
def euroc() -> Pair:
    return euroc_pair()


@pytest.fixture(scope="module")
def nav(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    node = NodeProcess(
        "stereo_node", NS, ros_env, tmp_path_factory.mktemp("clear_logs"), ["-p", "publish_points_clearing:=true"]
    )
    with ros.running([node]):
        collectors = {name: ros.collector(msg_type, f"{NS}/{name}") for name, msg_type in OUTPUTS.items()}
        for collector in collectors.values():
            wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
        inputs = StereoInput(ros, NS)
        inputs.wait_matched()
        yield {"inputs": inputs, "node": node, **collectors}


def send(ros: RosHarness, nav: dict[str, Any], pair: Pair, **options: Any) -> dict[str, Any]:
    """Set `options`, send the pair once, return every output of that frame; options restored."""
    outputs = {name: nav[name] for name in OUTPUTS}
    return send_with_parameters(ros, f"{NS}/stereo_node", nav["inputs"], outputs, pair, next(_stamps), **options)


def clearing_pixels(cloud: Any, info: Any, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(pixel index, z) of each clearing point, the pixel found by projecting it with depth/camera_info."""
    xyz = cloud_to_arrays(cloud)[0].reshape(-1, 3).astype(np.float64)
    k = np.reshape(info.k, (3, 3))
    u = k[0, 0] * xyz[:, 0] / xyz[:, 2] + k[0, 2]
    v = k[1, 1] * xyz[:, 1] / xyz[:, 2] + k[1, 2]
    assert np.abs(u - np.rint(u)).max() < 1e-3 and np.abs(v - np.rint(v)).max() < 1e-3  # on a pixel's ray
    return np.rint(v).astype(int) * shape[1] + np.rint(u).astype(int), xyz[:, 2]


def glare(left_rect: Any) -> np.ndarray:
    """The glare of the rectified left image (8-bit, as matched): saturated, no texture."""
    return glare_area(saturated(image_to_array(left_rect), 255)).ravel()


def test_pixels_beyond_max_depth_clear_out_to_the_clamp_and_never_mark(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair
) -> None:
    full = image_to_array(send(ros, nav, euroc, invalidate_saturated=False)["depth"])  # the window's depth too
    got = send(ros, nav, euroc, max_depth=5.0, clearing_max_depth=7.0, invalidate_saturated=False)
    cloud = got["points2_clearing"]
    assert (cloud.height, cloud.is_dense) == (1, True)
    pixels, z = clearing_pixels(cloud, got["depth/camera_info"], full.shape)
    beyond = full.ravel() > 5.0
    assert beyond.sum() > 1000 and (full.ravel() > 7.0).sum() > 100  # both rules bite on this scene
    message = got["disparity"]
    smallest = (disparity_from_msg(message) < message.min_disparity + 1).ravel()  # SGBM: d = 0 in glare
    expected = np.flatnonzero((beyond | smallest) & ~glare(got["left/image_rect"]))
    np.testing.assert_array_equal(pixels, expected)  # one point per such pixel, in pixel order
    np.testing.assert_array_equal(z.astype(np.float32), np.fmin(full.ravel()[expected], np.float32(7.0)))
    marked = cloud_to_arrays(got["points2"])[0][:, :, 2].ravel()
    assert not np.isfinite(marked[beyond]).any()  # never in points2
    assert not np.isfinite(image_to_array(got["depth"]).ravel()[beyond]).any()


def test_glare_casts_no_clearing_ray(ros: RosHarness, nav: dict[str, Any], euroc: Pair) -> None:
    """SGBM matches the window glare of the EuRoC room below 1 px (as if beyond 50 m): a clearing ray
    from there would clear whatever stands in front of it. (near_detection and invalidate_saturated off: they
    already drop most of those, the ones the confidence does not back and the glare itself.)"""
    got = send(ros, nav, euroc, clearing_max_depth=100.0, near_detection=False, invalidate_saturated=False)
    message = got["disparity"]
    smallest = (disparity_from_msg(message) < message.min_disparity + 1).ravel()
    in_glare = smallest & glare(got["left/image_rect"])
    assert in_glare.sum() > 500  # the glare this frame holds, matched at the smallest disparity
    shape = image_to_array(got["depth"]).shape
    pixels, _ = clearing_pixels(got["points2_clearing"], got["depth/camera_info"], shape)
    assert not np.isin(np.flatnonzero(in_glare), pixels).any()
    assert np.isin(np.flatnonzero(smallest & ~glare(got["left/image_rect"])), pixels).all()  # the rest still clear


def test_pixels_at_the_smallest_disparity_clear_even_without_max_depth(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair
) -> None:
    got = send(ros, nav, euroc, min_disparity=16, clearing_max_depth=100.0)
    depth = image_to_array(got["depth"])
    message = got["disparity"]
    d = disparity_from_msg(message)
    pixels, z = clearing_pixels(got["points2_clearing"], got["depth/camera_info"], depth.shape)
    smallest = np.flatnonzero(
        (d < message.min_disparity + 1).ravel() & ~glare(got["left/image_rect"])
    )  # NaN (not matched): never
    assert smallest.size > 500  # the farther half of the room saturates at 16 px
    np.testing.assert_array_equal(pixels, smallest)
    np.testing.assert_array_equal(z.astype(np.float32), depth.ravel()[smallest])  # as far as the matcher sees


@pytest.mark.parametrize(
    ("encoding", "codec"), [("32FC1", "png"), ("16UC1", "png"), ("32FC1", "rvl"), ("16UC1", "rvl")]
)
def test_compressed_depth_decodes_to_the_depth_image(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair, encoding: str, codec: str
) -> None:
    got = send(ros, nav, euroc, depth_encoding=encoding, compressed_depth_format=codec)
    compressed = got["depth/compressedDepth"]
    assert compressed.format == f"{encoding}; compressedDepth {codec}"
    assert compressed.header == got["depth"].header
    assert len(compressed.data) < len(got["depth"].data) / 2
    assert_decodes_to_depth(compressed, got["depth"], min_valid=0.5)


def test_rvl_sends_depth_with_nothing_valid_as_png_and_says_so_once(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair
) -> None:
    for _ in range(2):
        got = send(ros, nav, euroc, compressed_depth_format="rvl", max_depth=0.3)  # nothing so near
        assert got["depth/compressedDepth"].format == "32FC1; compressedDepth png"
        assert_decodes_to_depth(got["depth/compressedDepth"], got["depth"])
    node: NodeProcess = nav["node"]
    wait_until(lambda: RVL_FALLBACK_NOTE in node.output(), "the fallback logged")
    assert node.output().count(RVL_FALLBACK_NOTE) == 1


# ---------------------------------------------------------------- offline


def test_process_writes_both_on_request_and_neither_by_default(tmp_path: Path) -> None:
    out = tmp_path / "nav"
    outputs = ["depth", "depth/camera_info", "depth/compressedDepth", "points2", "points2_clearing", "left/image_rect"]
    # near_detection leaves out most far pixels the matcher is unsure of; invalidate_saturated the window's
    # far depth too: the clearing rule holds them back alone
    matched_glare = ["near_detection=false", "invalidate_saturated=false"]
    settings = [
        "depth_encoding=16UC1",
        "max_depth=5",
        "clearing_max_depth=7",
        "compressed_depth_max_depth=20",
        *matched_glare,
    ]
    args = ["process", str(BAG), str(out), "--outputs", *outputs, *(a for s in settings for a in ("--set", s))]
    assert main(args) == 0
    topics = {name: f"/stereo/{name}" for name in outputs}
    messages = read_messages(out, list(topics.values()))
    got = {name: messages[topic] for name, topic in topics.items()}
    assert all(len(m) == 6 for m in got.values())
    free = tmp_path / "free"
    extra = [a for s in matched_glare for a in ("--set", s)]
    assert main(["process", str(BAG), str(free), "--set", "depth_encoding=16UC1", *extra]) == 0
    full_depths = read_messages(free, ["/stereo/depth"])["/stereo/depth"]
    metadata = yaml.safe_load((free / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    written = {t["topic_metadata"]["name"] for t in metadata["topics_with_message_count"]}
    assert "/stereo/points2" in written  # the defaults: what stereo_node publishes unless told
    assert not written & {"/stereo/points2_clearing", "/stereo/depth/compressedDepth"}
    for index, full_msg in enumerate(full_depths):
        assert_decodes_to_depth(got["depth/compressedDepth"][index], got["depth"][index], depth_max=20.0, min_valid=0.5)
        full = image_to_array(full_msg).astype(np.float64) / 1000.0
        pixels, z = clearing_pixels(got["points2_clearing"][index], got["depth/camera_info"][index], full.shape)
        assert (full > 5.0).sum() > 1000
        beyond = np.flatnonzero((full > 5.0).ravel() & ~glare(got["left/image_rect"][index]))  # glare: no ray
        assert beyond.size > 300
        assert np.isin(beyond, pixels).all()
        at = np.searchsorted(pixels, beyond)
        np.testing.assert_allclose(z[at], np.minimum(full.ravel()[beyond], 7.0), atol=5e-4)  # depth: mm here
        assert np.nanmax(cloud_to_arrays(got["points2"][index])[0][:, :, 2]) <= 5.0


def test_compressed_depth_is_encoded_only_while_someone_subscribes(
    ros: RosHarness, ros_env: dict[str, str], euroc: Pair, tmp_path: Path
) -> None:
    node = NodeProcess("stereo_node", "/quiet", ros_env, tmp_path)
    with ros.running([node]):
        depth = ros.collector(Image, "/quiet/depth")
        diagnostics = ros.collector(DiagnosticArray, "/quiet/diagnostics")
        for collector in (depth, diagnostics):
            wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
        inputs = StereoInput(ros, "/quiet")
        inputs.wait_matched()

        def stages_once_reported(stage: str) -> set[str]:
            """The stage keys of the first diagnostics report (from now on) that times `stage`."""
            seen = len(diagnostics.messages)

            def reported() -> set[str] | None:
                for array in diagnostics.messages[seen:]:
                    keys = {kv.key for kv in array.status[0].values}
                    if stage in keys:
                        return keys
                return None

            keys: set[str] = wait_until(reported, f"a diagnostics report with {stage}")
            return keys

        wait_until_delivered(inputs, depth, euroc)  # the node's depth publisher has matched this collector
        stages = stages_once_reported("publish depth time (ms)")
        assert "publish depth/compressedDepth time (ms)" not in stages  # nobody listens: never built

        compressed = ros.collector(CompressedImage, "/quiet/depth/compressedDepth")
        wait_until(lambda: compressed.subscription.get_publisher_count() >= 1, "compressedDepth matched")
        stamp = next(_stamps)
        inputs.publish(euroc, stamp)
        assert_decodes_to_depth(compressed.wait_stamp(stamp), depth.wait_stamp(stamp))
        stages_once_reported("publish depth/compressedDepth time (ms)")
