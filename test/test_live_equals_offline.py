"""The live node and `stereo-depth process` give the same messages, field for field and bit for bit, for
the same bag: every output (disparity, depth, points2, confidence, left/image_rect), at the quality and
fast profiles, with two matching threads and with the cloud options. One short real bag (6 EuRoC frames)
replayed into a node.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rclpy.serialization import deserialize_message
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.bag.recording import open_reader
from stereo_depth.cli import main

BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"
NS = "/stereo"  # the bag's namespace; this file's node is the only one under it while it runs
FRAMES = 6
OUTPUTS = {
    "disparity": DisparityImage,
    "depth": Image,
    "points2": PointCloud2,
    "confidence": Image,
    "left/image_rect": Image,
}
CLOUD = {"organized_cloud": "false", "cloud_voxel_size": "0.05", "min_depth": "0.5", "max_depth": "8.0"}
LIVE_ONLY = ("matching_threads", "max_waiting_frames")  # how the node runs, not what it computes
# name: (stereo_node -p values, the outputs compared); `process` gets the same values with --set
VARIANTS = {
    "quality": (
        {"profile": "quality", "spatial_filter": "true"},  # invalidate_saturated on too: the bag holds a bright window
        ("disparity", "depth", "points2", "confidence", "left/image_rect"),
    ),
    "fast_two_threads": (
        {"profile": "fast", "matching_threads": "2"},
        ("disparity", "depth", "confidence", "left/image_rect"),
    ),
    "cloud_options": (CLOUD, ("disparity", "depth", "points2")),
}


def offline(tmp_path: Path, values: dict[str, str], outputs: tuple[str, ...]) -> dict[str, dict[int, Any]]:
    """`stereo-depth process` of the bag: {output: {stamp: message}}, as rclpy messages. (Field by field:
    CDR leaves padding bytes unspecified, and rclpy's are not zero.)"""
    settings = {name: value for name, value in values.items() if name not in (*LIVE_ONLY, "profile")}
    sets = [arg for name, value in settings.items() for arg in ("--set", f"{name}={value}")]
    profile = ["--profile", values["profile"]] if "profile" in values else []
    out = tmp_path / "offline"
    assert main(["process", str(BAG), str(out), *profile, *sets, "--outputs", *outputs]) == 0
    found: dict[str, dict[int, Any]] = {name: {} for name in outputs}
    reader = open_reader(out)
    try:
        for connection, log_time, raw in reader.messages(reader.connections):
            name = connection.topic.removeprefix(f"{NS}/")
            found[name][log_time] = deserialize_message(bytes(raw), OUTPUTS[name])
    finally:
        reader.close()
    return found


@pytest.fixture(params=list(VARIANTS))
def variant(
    request: pytest.FixtureRequest, ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> Iterator[tuple[str, dict[str, Any], dict[str, dict[int, Any]]]]:
    """A node with the variant's parameters (room for every frame: none dropped), its outputs collected."""
    values, outputs = VARIANTS[request.param]
    args = [arg for name, value in {**values, "max_waiting_frames": "10"}.items() for arg in ("-p", f"{name}:={value}")]
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path, args)
    with ros.running([node]):
        collectors = {name: ros.collector(OUTPUTS[name], f"{NS}/{name}") for name in outputs}
        for name, collector in collectors.items():
            wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, f"{name} matched")
        yield request.param, collectors, offline(tmp_path, values, outputs)


def test_the_node_publishes_what_process_writes_bit_for_bit(
    variant: tuple[str, dict[str, Any], dict[str, dict[int, Any]]], ros_env: dict[str, str]
) -> None:
    name, collectors, expected = variant
    command = [sys.executable, "-m", "stereo_depth.cli", "replay", str(BAG)]
    command += [
        "--wait-for-subscribers",
        "1",
        "--topics",
        *(f"{NS}/{side}/{kind}" for side in ("left", "right") for kind in ("image_raw", "camera_info")),
    ]
    replay = subprocess.run(command, env=ros_env, capture_output=True, text=True, timeout=120, check=False)
    assert replay.returncode == 0, replay.stderr
    last = max(expected["disparity"])
    # one matching thread: every frame (room for all of them to wait); two: a frame that a newer one
    # overtook is dropped, never the newest
    everything = "matching_threads" not in VARIANTS[name][0]
    for output, collector in collectors.items():
        wait_until(
            lambda c=collector: len(c.messages) >= FRAMES or (not everything and last in c.stamps()),
            f"{name}: the frames of {output}",
            120.0,
        )
        live = dict(zip(collector.stamps(), collector.messages, strict=True))
        assert len(expected[output]) == FRAMES and (len(live) == FRAMES or not everything), output
        assert live == {stamp: expected[output][stamp] for stamp in live}, f"{name}: {output} differs"
