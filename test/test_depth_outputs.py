"""Depth that navigation and mapping stacks take as it is: each output option of stereo_node over real
DDS on the raw, distorted EuRoC pair (its rectification moves pixels), and the same options offline.

One stereo_node (/nav) serves the module; each test sets the options it pins with `ros2 param set`,
sends the pair with a fresh stamp and restores the defaults.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage
from test_nodes import Pair, StereoInput, euroc_pair, send_with_parameters

from stereo_depth.bag.reader import read_messages
from stereo_depth.cli import main
from stereo_depth.messages import cloud_to_arrays, disparity_from_msg, image_to_array, stamp_to_ns
from stereo_depth.options import OutputOptions

NS = "/nav"
BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"
DEFAULTS = {name: getattr(OutputOptions(), name) for name in ("depth_encoding", "min_depth", "max_depth")}
_stamps = itertools.count(1_800_000_000 * 10**9, 250_000_000)  # 4 Hz of stamps


@pytest.fixture(scope="module")
def euroc() -> Pair:
    return euroc_pair()


@pytest.fixture(scope="module")
def nav(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path_factory.mktemp("nav_logs"))
    with ros.running([node]):
        yield nav_outputs(ros, node)


def nav_outputs(ros: RosHarness, node: NodeProcess) -> dict[str, Any]:
    outputs = {
        "disparity": ros.collector(DisparityImage, f"{NS}/disparity"),
        "depth": ros.collector(Image, f"{NS}/depth"),
        "depth/camera_info": ros.collector(CameraInfo, f"{NS}/depth/camera_info"),
        "points2": ros.collector(PointCloud2, f"{NS}/points2"),
    }
    for collector in outputs.values():
        wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
    inputs = StereoInput(ros, NS)
    inputs.wait_matched()
    return {"node": node, "inputs": inputs, **outputs}


def send(ros: RosHarness, nav: dict[str, Any], pair: Pair, wanted: tuple[str, ...], **options: Any) -> dict[str, Any]:
    """Set `options`, send the pair once, return the `wanted` outputs of that frame; options restored."""
    outputs = {name: nav[name] for name in wanted}
    return send_with_parameters(ros, f"{NS}/stereo_node", nav["inputs"], outputs, pair, next(_stamps), **options)


def xyz_of(cloud: Any) -> np.ndarray:
    return cloud_to_arrays(cloud)[0].reshape(-1, 3)


@pytest.mark.parametrize(
    "downsample", [{}, {"downsample": 2}, {"downsample": 2, "downsample_output": "processed"}], ids=str
)
def test_depth_camera_info_describes_the_depth_image(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair, downsample: dict[str, Any]
) -> None:
    got = send(ros, nav, euroc, ("depth", "depth/camera_info", "points2", "disparity"), **downsample)
    depth, info, cloud = got["depth"], got["depth/camera_info"], got["points2"]
    assert info.header == depth.header and (info.width, info.height) == (depth.width, depth.height)
    factor = 2 if downsample.get("downsample_output") == "processed" else 1
    assert (info.width, info.height) == (752 // factor, 480 // factor)
    k, p = np.reshape(info.k, (3, 3)), np.reshape(info.p, (3, 4))
    np.testing.assert_array_equal(k, p[:, :3])
    assert not np.any(info.d) and np.array_equal(np.reshape(info.r, (3, 3)), np.eye(3))
    assert k[0, 0] == pytest.approx(got["disparity"].f, rel=1e-7)  # the disparity's focal length (float32 there)
    # the model projects every point of the same frame back onto its own depth pixel
    z = image_to_array(depth)
    v, u = np.nonzero(np.isfinite(z))
    xyz = cloud_to_arrays(cloud)[0][v, u].astype(np.float64)
    np.testing.assert_allclose(k[0, 0] * xyz[:, 0] / xyz[:, 2] + k[0, 2], u, atol=1e-3)
    np.testing.assert_allclose(k[1, 1] * xyz[:, 1] / xyz[:, 2] + k[1, 2], v, atol=1e-3)


def test_16uc1_depth_is_rounded_millimetres_of_the_disparity(ros: RosHarness, nav: dict[str, Any], euroc: Pair) -> None:
    got = send(ros, nav, euroc, ("depth", "disparity"), depth_encoding="16UC1")
    assert got["depth"].encoding == "16UC1"
    mm = image_to_array(got["depth"]).astype(np.int64)
    message = got["disparity"]
    d = disparity_from_msg(message).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        expected = np.round(1000.0 * message.f * message.t / d)
    expected[~(expected <= 65535)] = 0  # invalid (NaN) and beyond 65.535 m: 0, as REP 118 says
    assert (mm > 0).mean() > 0.5
    assert np.abs(mm - expected).max() <= 1  # float32 depth: a .5 tie may round the other way
    assert (mm == expected).mean() > 0.999


def test_depth_limits_invalidate_depth_and_points_but_not_disparity(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair
) -> None:
    wanted = ("depth", "points2", "disparity")
    free = send(ros, nav, euroc, wanted)
    limited = send(ros, nav, euroc, wanted, min_depth=3.0, max_depth=6.0)
    full = image_to_array(free["depth"])
    assert (full < 3.0).any() and (full > 6.0).any()  # the limits bite on this scene
    for z in (image_to_array(limited["depth"]), xyz_of(limited["points2"])[:, 2]):
        valid = z[np.isfinite(z)]
        assert valid.size > 1000 and valid.min() >= 3.0 and valid.max() <= 6.0
    kept = image_to_array(limited["depth"])
    inside = (full >= 3.0) & (full <= 6.0)
    np.testing.assert_array_equal(kept[inside], full[inside])
    np.testing.assert_array_equal(disparity_from_msg(limited["disparity"]), disparity_from_msg(free["disparity"]))


def raw_sources(info: Any, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixel (row, column) each rectified pixel samples, from OpenCV's own float maps."""
    map_x, map_y = cv2.initUndistortRectifyMap(info.k, info.d, info.r, info.p[:, :3], shape[::-1], cv2.CV_32FC1)
    return np.rint(map_y).astype(int), np.rint(map_x).astype(int)


def test_mask_drawn_on_the_raw_image_hides_its_pixels_after_rectification(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair, tmp_path: Path
) -> None:
    mask = np.full((480, 752), 255, np.uint8)
    mask[300:, :300] = 0  # the robot's body in the lower left corner, where distortion is strong
    path = tmp_path / "body.png"
    cv2.imwrite(str(path), mask)
    got = send(ros, nav, euroc, ("depth", "points2"), mask_image=str(path))
    free = image_to_array(send(ros, nav, euroc, ("depth",))["depth"])
    rows, cols = raw_sources(euroc.left_info, mask.shape)
    inside = (rows >= 0) & (rows < 480) & (cols >= 0) & (cols < 752)
    hidden = np.zeros(mask.shape, bool)
    hidden[inside] = mask[rows[inside], cols[inside]] == 0
    assert (hidden != (mask == 0)).mean() > 0.01  # rectification moved the region: raw coordinates would be wrong
    depth = image_to_array(got["depth"])
    assert not np.isfinite(depth[hidden]).any()
    assert not np.isfinite(cloud_to_arrays(got["points2"])[0][hidden]).any()
    assert np.isfinite(free[hidden]).mean() > 0.3  # there was depth there to hide
    away = ~cv2.dilate(hidden.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    np.testing.assert_array_equal(depth[away], free[away])  # nothing else changed


def test_unorganized_cloud_is_the_valid_depth_pixels_and_voxels_thin_it(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair
) -> None:
    dense = send(ros, nav, euroc, ("depth", "points2"), organized_cloud=False)
    cloud = dense["points2"]
    z = image_to_array(dense["depth"])
    xyz = xyz_of(cloud)
    assert (cloud.height, cloud.is_dense) == (1, True) and not np.isnan(xyz).any()
    assert cloud.width == np.isfinite(z).sum() > 1000
    np.testing.assert_array_equal(xyz[:, 2], z[np.isfinite(z)])  # row-major pixel order

    size = 0.2
    thinned = send(ros, nav, euroc, ("points2",), organized_cloud=False, cloud_voxel_size=size)["points2"]
    occupied = {tuple(c) for c in np.floor(xyz / np.float32(size)).astype(np.int64)}
    centres = np.floor(xyz_of(thinned) / np.float32(size)).astype(np.int64)
    assert thinned.width == len(occupied) < cloud.width / 10
    assert np.mean([tuple(c) in occupied for c in centres]) > 0.999  # a centroid stays in its voxel


def test_points_max_rate_limits_clouds_by_stamp_not_depth(ros: RosHarness, nav: dict[str, Any], euroc: Pair) -> None:
    fqn = f"{NS}/stereo_node"
    assert ros.set_parameters(fqn, points_max_rate=1.0)[0].successful
    try:
        stamps = [next(_stamps) for _ in range(9)]  # 4 Hz of stamps over 2 s
        for stamp in stamps:  # one at a time: no frame is dropped for being sent too fast
            nav["inputs"].publish(euroc, stamp)
            nav["depth"].wait_stamp(stamp)
        wait_until(lambda: stamps[-1] in nav["points2"].stamps(), "the last cloud")
    finally:
        ros.set_parameters(fqn, points_max_rate=0.0)
    clouds = [s for s in nav["points2"].stamps() if s >= stamps[0]]
    assert clouds == stamps[::4]  # 0, 1 and 2 s: at most 1 Hz, and no due cloud left out


def test_process_takes_the_same_options_from_a_params_file(tmp_path: Path) -> None:
    params = tmp_path / "nav.yaml"
    options = {"depth_encoding": "16UC1", "organized_cloud": False, "max_depth": 5.0, "points_max_rate": 1.0}
    params.write_text(yaml.safe_dump({"stereo_node": {"ros__parameters": options}}))
    out = tmp_path / "out"
    assert main(["process", str(BAG), str(out), "--params", str(params)]) == 0
    topics = [f"/stereo/{name}" for name in ("depth", "depth/camera_info", "points2")]
    messages = read_messages(out, topics)
    depths, infos, clouds = (messages[t] for t in topics)
    assert len(depths) == len(infos) == 6 and all(d.encoding == "16UC1" for d in depths)
    assert all(i.header.stamp == d.header.stamp and i.width == d.width for i, d in zip(infos, depths, strict=True))
    assert all(image_to_array(d).max() <= 5000 for d in depths)
    assert all(c.height == 1 and c.is_dense for c in clouds)
    # frames 0.6 s apart: at most 1 Hz by stamp, and a frame 1 s or more after the last cloud has one
    cloud_stamps = [stamp_to_ns(c.header.stamp) for c in clouds]
    assert cloud_stamps[0] == stamp_to_ns(depths[0].header.stamp) and len(clouds) < len(depths)
    assert all(b - a >= 1_000_000_000 for a, b in itertools.pairwise(cloud_stamps))
    for depth in depths:
        stamp = stamp_to_ns(depth.header.stamp)
        last = max(s for s in cloud_stamps if s <= stamp)
        assert stamp == last or stamp - last < 1_000_000_000


@pytest.mark.parametrize("decimation", [2, 4])
def test_points_decimation_keeps_every_nth_pixel_of_the_full_cloud_bit_for_bit(
    ros: RosHarness, nav: dict[str, Any], euroc: Pair, decimation: int
) -> None:
    """An organized cloud of every Nth row and column: each point that pixel's own point of the full
    cloud (its ray and depth, its colour), no averaging; the depth image stays at full size."""
    wanted = ("depth", "points2")
    full = send(ros, nav, euroc, wanted)
    thin = send(ros, nav, euroc, wanted, points_decimation=decimation)
    assert (thin["depth"].height, thin["depth"].width) == (full["depth"].height, full["depth"].width)
    height, width = full["points2"].height, full["points2"].width
    assert (thin["points2"].height, thin["points2"].width) == (height // decimation, width // decimation)
    full_xyz, full_rgb = cloud_to_arrays(full["points2"])
    thin_xyz, thin_rgb = cloud_to_arrays(thin["points2"])
    kept = (slice(None, None, decimation), slice(None, None, decimation))
    assert np.isfinite(thin_xyz).any()
    assert full_xyz[kept].tobytes() == thin_xyz.tobytes()  # NaN where NaN, every bit of the rest
    assert full_rgb is not None and thin_rgb is not None and np.array_equal(full_rgb[kept], thin_rgb)
