"""The repository is a real ament_python package: colcon builds it into a ROS workspace layout."""

from __future__ import annotations

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


@pytest.mark.parametrize("exported", ["", "/my/profile.xml"], ids=["no profile", "the user's profile"])
def test_sourcing_the_workspace_exports_the_large_message_profile_unless_one_is_set(
    install_tree: Path, exported: str
) -> None:
    """`source install/setup.sh` gives a driver, RViz or Nav2 started from that shell our Fast DDS profile
    (colcon.pkg's hook), and never replaces one the user exported."""
    env = {"HOME": os.environ.get("HOME", "/tmp"), "PATH": "/usr/bin:/bin"}
    if exported:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = exported
    script = f'. "{install_tree.parent / "local_setup.sh"}" && echo "$FASTRTPS_DEFAULT_PROFILES_FILE"'
    shown = subprocess.run(["sh", "-c", script], env=env, capture_output=True, text=True, check=True).stdout.strip()
    if exported:
        assert shown == exported
    else:
        assert shown == str(install_tree / "share" / "stereo_depth" / "config" / "fastdds_large_images.xml")
        assert Path(shown).is_file()
