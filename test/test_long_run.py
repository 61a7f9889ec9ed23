"""A long run over DDS: 2,000 frames lose nothing and grow no memory; too many frames stay fresh.

Drives stereo_node with bench/soak.py's `Soak` (the same publisher and bookkeeping the soak script
prints from). Small frames and the `fast` profile keep the sustainable rate well above the one used
here, even on a busy 2-core machine. Time is asserted only as the bound the issue asks for.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from ros_helpers import NodeProcess, RosHarness, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from soak import Soak, rss_mb

NS = "/long_run"
WIDTH, HEIGHT = 160, 120
SUSTAINABLE_HZ = 30.0  # a common camera rate; the node keeps only the newest set, so it must keep up
FRAMES = 2_000
WARM_UP_FRAMES = 100


@pytest.fixture(scope="module")
def node(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[NodeProcess]:
    process = NodeProcess("stereo_node", NS, ros_env, tmp_path_factory.mktemp("long_run"), ["-p", "profile:=fast"])
    ros.wait_for_nodes([process])
    yield process
    code, output = process.stop()
    assert code == 0 and "Traceback" not in output, output


def warm_up(driver: Soak, frames: int) -> None:
    """One frame at a time: first-frame work (maps, JIT, allocations) is not what is measured."""
    for _ in range(frames):
        driver.publish()
        sent = (len(driver.sent) - 1, len(driver.sent))
        wait_until(lambda s=sent: driver.window(s, settle_s=0.0).received, "a warm-up frame")


@pytest.fixture(scope="module")
def soak(ros: RosHarness, node: NodeProcess) -> Soak:
    driver = Soak(ros.node, NS, WIDTH, HEIGHT)
    driver.wait_matched()
    warm_up(driver, WARM_UP_FRAMES)
    return driver


def test_two_thousand_frames_at_a_sustainable_rate_lose_nothing_and_grow_no_memory(
    ros: RosHarness, soak: Soak, node: NodeProcess
) -> None:
    # As the README advises for runs that must not lose frames: a few waiting places ride out the
    # machine's scheduling hiccups (a 200 ms stall of a busy 2-core VM would cost the newest-only
    # default six frames); a node slower than the input still fills them and loses frames.
    fqn = f"{NS}/stereo_node"
    assert all(r.successful for r in ros.set_parameters(fqn, max_waiting_frames=10))
    try:
        rss_before = rss_mb(node.process.pid)
        window = soak.window(soak.run(SUSTAINABLE_HZ, frames=FRAMES), settle_s=10.0)
        growth = rss_mb(node.process.pid) - rss_before
    finally:
        ros.set_parameters(fqn, max_waiting_frames=1)
    print(f"\n{FRAMES} frames {WIDTH}x{HEIGHT} at {SUSTAINABLE_HZ} Hz: {window.line()}  rss growth {growth:+.1f} MB")
    assert window.sent == FRAMES
    assert window.lost == 0, window.line()
    assert growth < 20.0
    assert node.process.poll() is None


def test_at_an_unsustainable_rate_latency_stays_bounded_and_drops_are_counted(
    ros: RosHarness, soak: Soak, node: NodeProcess
) -> None:
    slow = {"downsample": 1, "matcher": "census_sgm"}  # several times slower than the input rate
    fqn = f"{NS}/stereo_node"
    assert all(r.successful for r in ros.set_parameters(fqn, **slow))
    try:
        warm_up(soak, 2)
        dropped_before = soak.node_count("dropped frames")
        window = soak.window(soak.run(SUSTAINABLE_HZ * 2, frames=500), settle_s=5.0)
        time.sleep(2.5)  # two diagnostics periods: the node's counters include this burst
        dropped = soak.node_count("dropped frames") - dropped_before
        print(f"\nunsustainable: {window.line()}  node dropped {dropped}")
        assert 0 < window.received < window.sent
        assert dropped > 0  # old frames were replaced and counted, not queued
        assert sorted(window.latency_ms)[int(0.95 * len(window.latency_ms))] < 1000.0
    finally:
        ros.set_parameters(fqn, downsample=2, matcher="bm", disparity_range=64)
    assert node.process.poll() is None
