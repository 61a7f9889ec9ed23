"""Shared test fixtures: real data paths and a DDS environment that stays on this machine."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

DATA = Path(__file__).parent / "data"
SCENES = DATA / "scenes"
EUROC = DATA / "euroc"


@pytest.fixture(scope="session")
def ros_env() -> dict[str, str]:
    """Environment for node subprocesses: loopback discovery only, this run's domain id."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", "42")
    env["PYTHONUNBUFFERED"] = "1"
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", env["ROS_DOMAIN_ID"])
    return env


@pytest.fixture(scope="module")
def ros(ros_env: dict[str, str]) -> Iterator[Any]:
    """A node in the test process to publish, collect and set parameters over real DDS."""
    from ros_helpers import RosHarness  # rclpy only for the modules that talk to nodes

    harness = RosHarness()
    yield harness
    harness.close()


@pytest.fixture(scope="session", autouse=True)
def compiled_census_core() -> None:
    """numba compiles census_sgm once per machine (~30 s, then cached beside the module): do it here,
    before any test waits with a timeout on a node process that would otherwise compile it."""
    import numpy as np

    from stereo_depth.core.census_sgm import census_sgm, fill_holes

    image = np.zeros((24, 48), np.uint8)
    disparity, _ = census_sgm(
        image,
        image,
        min_disparity=0,
        num_disparities=16,
        window_size=1,
        P1=20,
        P2=200,
        uniqueness_ratio=3,
        disp12_max_diff=1,
    )
    fill_holes(disparity, image)
