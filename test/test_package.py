"""The repository is a real ament_python package: colcon builds it into a ROS workspace layout."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NODES = ("stereo_node", "stereo_lifecycle_node", "disparity_node", "point_cloud_node", "rectify_node")


@pytest.fixture(scope="module")
def install_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    colcon = Path(sys.executable).with_name("colcon")
    if not colcon.exists():
        colcon = Path(shutil.which("colcon") or "colcon")
    work = tmp_path_factory.mktemp("ws")
    subprocess.run(
        [
            str(colcon),
            "--log-base",
            str(work / "log"),
            "build",
            "--base-paths",
            str(ROOT),
            "--build-base",
            str(work / "build"),
            "--install-base",
            str(work / "install"),
        ],
        cwd=work,
        check=True,
        capture_output=True,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
        timeout=600,
    )
    return work / "install" / "stereo_depth"


@pytest.mark.parametrize("node", NODES)
def test_colcon_installs_each_node_where_ros2_run_finds_it(install_tree: Path, node: str) -> None:
    script = install_tree / "lib" / "stereo_depth" / node
    assert script.is_file()
    assert os.access(script, os.X_OK)


def test_colcon_install_has_ament_index_marker_launch_and_config(install_tree: Path) -> None:
    share = install_tree / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / "stereo_depth").is_file()
    assert (share / "stereo_depth" / "package.xml").is_file()
    assert (share / "stereo_depth" / "launch" / "stereo_depth.launch.py").is_file()
    assert (share / "stereo_depth" / "config" / "stereo_depth.yaml").is_file()


VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")  # Fast DDS 2 (Jazzy), 3


@pytest.mark.parametrize("exported", [None, *VARIABLES], ids=["no profile", "Fast DDS 2 profile", "Fast DDS 3 profile"])
def test_sourcing_the_workspace_exports_the_large_message_profile_unless_one_is_set(
    install_tree: Path, exported: str | None
) -> None:
    """`source install/setup.sh` gives a driver, RViz or Nav2 started from that shell our Fast DDS profile
    (colcon.pkg's hook) in both variables, and changes neither when the user exported either one."""
    env = {"HOME": os.environ.get("HOME", "/tmp"), "PATH": "/usr/bin:/bin"}
    if exported:
        env[exported] = "/my/profile.xml"
    show = " && ".join(f'echo "{name}=${{{name}:-}}"' for name in VARIABLES)
    script = f'. "{install_tree.parent / "local_setup.sh"}" && {show}'
    run = subprocess.run(["sh", "-c", script], env=env, capture_output=True, text=True, check=True, timeout=60)
    shown = run.stdout.split()
    ours = install_tree / "share" / "stereo_depth" / "config" / "fastdds_large_images.xml"
    if exported:
        assert shown == [f"{name}={env.get(name, '')}" for name in VARIABLES]
    else:
        assert shown == [f"{name}={ours}" for name in VARIABLES]
        assert ours.is_file()


ROS_FREE = (
    "rclpy",
    "rosbags",
    "sensor_msgs",
    "stereo_msgs",
    "stereo_depth.ros",
    "stereo_depth.nodes",
    "stereo_depth.bag",
    "stereo_depth.commands",
)


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    return names | {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}


@pytest.mark.parametrize(
    ("layer", "forbidden"),
    [
        ("ros", ("stereo_depth.bag",)),
        ("core", (*ROS_FREE, "yaml", "stereo_depth.frames", "stereo_depth.messages")),
        ("frames", ROS_FREE),
    ],
)
def test_layers_import_only_what_the_design_lets_them(layer: str, forbidden: tuple[str, ...]) -> None:
    """DESIGN.md's layers: ros/ never imports bag/; core/ is numpy, OpenCV and numba, no ROS, rosbags or yaml;
    the frame layer is ROS-free too, and neither imports the layers above them (ros/, nodes/, bag/)."""
    package = Path(__file__).parents[1] / "stereo_depth" / layer
    found = {
        f"{path.relative_to(package.parent)}: {name}"
        for path in package.rglob("*.py")
        for name in _imports(path)
        if any(name == f or name.startswith(f"{f}.") for f in forbidden)
    }
    assert not found


# The core's own thread helper: it runs the core's work (a half of a frame) on another core, never a caller's.
OWN_WORK_RUNNERS = {"core/threads.py: OtherCore.submit(job)"}


def _callable_parameters(path: Path, package: Path) -> set[str]:
    """Each parameter annotated as a Callable (or an Optional one), of any function or method, nested ones
    too, as "file: function(parameter)", a method's function named Class.method."""
    tree = ast.parse(path.read_text())
    owners = {
        id(function): f"{owner.name}."
        for owner in ast.walk(tree)
        if isinstance(owner, ast.ClassDef)
        for function in owner.body
    }
    found = set()
    for function in ast.walk(tree):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        arguments = function.args
        for argument in [*arguments.posonlyargs, *arguments.args, *arguments.kwonlyargs]:
            if argument.annotation is not None and "Callable" in ast.unparse(argument.annotation):
                name = f"{owners.get(id(function), '')}{function.name}({argument.arg})"
                found.add(f"{path.relative_to(package.parent)}: {name}")
    return found


@pytest.mark.parametrize("layer", ["frames", "core"])
def test_frame_layer_and_core_take_no_callable_from_their_callers(layer: str) -> None:
    """Data flows down and returns: no function of the frame layer or the core takes a callback (a parameter
    annotated as a Callable), so none of them can call back into a node or a command."""
    package = Path(__file__).parents[1] / "stereo_depth" / layer
    found = {name for path in package.rglob("*.py") for name in _callable_parameters(path, package)}
    assert found - OWN_WORK_RUNNERS == set()
