"""Shared test fixtures: real data paths and a DDS environment that stays on this machine."""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import pytest
from parent_death import die_with_parent

from stereo_depth.core.camera import StereoCamera
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.scenes import load_scene

if TYPE_CHECKING:
    from ros_helpers import NodeProcess

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from lib.domain_lock import claim_domain_id  # the benches lock their domain ids alike

DATA = Path(__file__).parent / "data"
SCENES = DATA / "scenes"
EUROC = DATA / "euroc"


def read_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    """cv2.imread that fails loudly: a missing or unreadable test file is an error, not None."""
    image = cv2.imread(str(path), flags)
    assert image is not None, f"cannot read {path}"
    return image


def euroc_sequence(folder: Path, frames: int) -> Path:
    """A EuRoC-style sequence folder (left/, right/, the calibration) holding the bundled EuRoC frames
    over and over, 0.1 s apart: a moving camera for as many frames as a test needs."""
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
        images = sorted((EUROC / side).glob("*.png"))
        for k in range(frames):
            shutil.copy(images[k % len(images)], folder / side / f"{1_000_000_000 + k * 100_000_000}.png")
    for name in ("cam0_sensor.yaml", "cam1_sensor.yaml"):
        shutil.copy(EUROC / name, folder / name)
    return folder


def grey_pairs() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Rectified grey pairs to match: three Middlebury scenes and a EuRoC frame (rectified here)."""
    pairs: list[tuple[str, np.ndarray, np.ndarray]] = []
    for name in ("artl", "cones", "tsukuba"):
        scene = load_scene(SCENES / name)
        left_grey, right_grey = (cv2.cvtColor(i, cv2.COLOR_BGR2GRAY) for i in (scene.left, scene.right))
        pairs.append((name, left_grey, right_grey))
    left = sorted((EUROC / "left").glob("*.png"))[0]
    camera = StereoCamera(*stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml", "cam"))
    raw = [read_image(EUROC / side / left.name, cv2.IMREAD_GRAYSCALE) for side in ("left", "right")]
    pairs.append(("euroc", camera.rectify(raw[0], "left"), camera.rectify(raw[1], "right")))
    return pairs


CALIBRATION_RTOL = 1e-9  # two computations of one calibration (file formats, code paths): not bit for bit


def assert_same_calibration(got: Any, expected: Any, what: object = "") -> None:
    """The same camera within CALIBRATION_RTOL of the largest entry of each matrix: a calibration read two
    ways goes through different float operations, and numpy / OpenCV versions round them differently."""
    assert (got.width, got.height, got.distortion_model) == (expected.width, expected.height, expected.distortion_model)
    for name in ("k", "d", "r", "p"):
        a, b = np.asarray(getattr(got, name)), np.asarray(getattr(expected, name))
        scale = max(1.0, float(np.abs(b).max(initial=0.0)))
        np.testing.assert_allclose(a, b, rtol=0, atol=CALIBRATION_RTOL * scale, err_msg=f"{what} {name}")


def pytest_configure(config: pytest.Config) -> None:
    """An xdist worker dies with the pytest that started it (and its nodes with it: parent_death.py); else a
    worker in a hung test would outlive a killed run until its timeout."""
    del config
    if "PYTEST_XDIST_WORKER" in os.environ:
        die_with_parent(os.getppid())


@pytest.fixture(scope="session", autouse=True)
def ros_env() -> dict[str, str]:
    """Environment for node subprocesses: loopback discovery only, a domain id of this run's own (set in
    os.environ too, before any test starts rclpy in this process)."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["ROS_DOMAIN_ID"] = str(claim_domain_id())
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture(scope="module")
def ros(ros_env: dict[str, str]) -> Iterator[Any]:
    """A node in the test process to publish, collect and set parameters over real DDS."""
    from ros_helpers import RosHarness  # rclpy only for the modules that talk to nodes

    harness = RosHarness()
    yield harness
    harness.close()


@pytest.fixture
def start_node(ros_env: dict[str, str], tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """Starts node processes for one test (NodeProcess's arguments, the run's environment and the test's
    folder unless given) and stops those still running when the test ends, whatever happened in it."""
    from ros_helpers import NodeProcess, stop_all

    started: list[NodeProcess] = []

    def start(
        module: str, namespace: str, args: Iterable[str] = (), *, env: dict[str, str] | None = None, **kwargs: Any
    ) -> NodeProcess:
        started.append(NodeProcess(module, namespace, env or ros_env, tmp_path, args, **kwargs))
        return started[-1]

    yield start
    stop_all(started, expect_clean=False)


@pytest.fixture(scope="session", autouse=True)
def no_node_outlives_the_run() -> Iterator[None]:
    """Every node a test starts is stopped by its fixture or test. One still running when the run ends
    (after every module's fixtures) is killed here, and the run fails, naming it: it would otherwise answer
    the next run on this domain id and keep a CI machine busy."""
    yield
    helpers = sys.modules.get("ros_helpers")  # loaded only by the tests that start nodes
    alive = [node for node in helpers.NodeProcess.started if node.process.poll() is None] if helpers else []
    for node in alive:
        node.process.kill()
        node.process.wait()
    assert not alive, f"node processes still running at the end of the run (killed): {[n.fqn for n in alive]}"


@pytest.fixture(scope="session", autouse=True)
def compiled_census_core() -> None:
    """numba compiles census_sgm once per machine (a minute or two, then cached beside the module): do it here,
    as `stereo-depth compile` does, before any test waits with a timeout on a node process that would
    otherwise compile it."""
    from stereo_depth.core.census_sgm import compile_kernels

    compile_kernels()


NODE_LOG_SHOWN = 6000  # characters of each node's output in a failing test's report


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Any:
    """A failing test's report ends with the output of the nodes that ran during it (their logs are files
    in a temporary folder, where CI's report would never show them)."""
    del item
    report = yield
    helpers = sys.modules.get("ros_helpers")  # loaded only by the tests that start nodes
    if report.failed and call.when == "call" and helpers is not None:
        for node in helpers.NodeProcess.started:
            if node.stopped_at is None or node.stopped_at >= call.start:
                report.sections.append((f"output of {node.fqn}", node.output()[-NODE_LOG_SHOWN:]))
    return report
