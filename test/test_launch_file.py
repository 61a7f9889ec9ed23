"""launch/stereo_depth.launch.py, checked without ROS 2's `launch` (it is not on PyPI, so the file is never
imported by a user of the wheels): its source runs with stand-ins for the five names it takes from
`launch` and `launch_ros`, which record what it asks for. Every layout its arguments choose is built;
each node it names must be an executable of this package, each remap must rename a topic that node
really has (read from the ROS graph of the node running), and each argument it documents must change
what is launched.
"""

from __future__ import annotations

import ast
import importlib.metadata
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from ros_helpers import NodeProcess, RosHarness, wait_until

from stereo_depth.core.params import PROFILES

LAUNCH = Path(__file__).resolve().parents[1] / "launch" / "stereo_depth.launch.py"
NS = "/launch_check"
LAYOUTS = [{"split_nodes": split, "color": color} for split in ("false", "true") for color in ("false", "true")]


class Action:
    """Stands in for DeclareLaunchArgument, OpaqueFunction and launch_ros's Node: keeps its arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


@dataclass
class Context:
    """A launch context: the argument values given."""

    values: dict[str, str]


class LaunchConfiguration:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: Context) -> str:
        return context.values[self.name]


def stand_ins() -> dict[str, ModuleType]:
    modules = {name: ModuleType(name) for name in ("launch", "launch.actions", "launch.substitutions")}
    modules |= {name: ModuleType(name) for name in ("launch_ros", "launch_ros.actions")}
    modules["launch"].LaunchContext = Context  # type: ignore[attr-defined]
    modules["launch"].LaunchDescription = list  # type: ignore[attr-defined]
    modules["launch.actions"].DeclareLaunchArgument = Action  # type: ignore[attr-defined]
    modules["launch.actions"].OpaqueFunction = Action  # type: ignore[attr-defined]
    modules["launch.substitutions"].LaunchConfiguration = LaunchConfiguration  # type: ignore[attr-defined]
    modules["launch_ros.actions"].Node = Action  # type: ignore[attr-defined]
    return modules


@pytest.fixture(scope="module")
def launch_file() -> Iterator[dict[str, Any]]:
    """The launch file's globals, run from its source with the stand-ins in place of launch."""
    source = LAUNCH.read_text()
    code = compile(ast.parse(source, str(LAUNCH)), str(LAUNCH), "exec")
    with pytest.MonkeyPatch.context() as patch:
        for name, module in stand_ins().items():
            patch.setitem(sys.modules, name, module)
        namespace: dict[str, Any] = {"__name__": "stereo_depth_launch", "__file__": str(LAUNCH)}
        exec(code, namespace)
        yield namespace


@dataclass
class Declared:
    defaults: dict[str, str]
    descriptions: dict[str, str]
    build: Any  # the OpaqueFunction's function: context -> nodes


def declared(launch_file: dict[str, Any]) -> Declared:
    actions = launch_file["generate_launch_description"]()
    arguments = [a for a in actions if "default_value" in a.kwargs]
    (opaque,) = [a for a in actions if "function" in a.kwargs]
    return Declared(
        defaults={a.args[0]: a.kwargs["default_value"] for a in arguments},
        descriptions={a.args[0]: a.kwargs["description"] for a in arguments},
        build=opaque.kwargs["function"],
    )


def launched(launch_file: dict[str, Any], **values: str) -> list[dict[str, Any]]:
    """The nodes (their keyword arguments) for these argument values."""
    arguments = declared(launch_file)
    return [node.kwargs for node in arguments.build(Context({**arguments.defaults, **values}))]


def console_scripts() -> set[str]:
    return {entry.name for entry in importlib.metadata.distribution("stereo_depth").entry_points}


def test_every_node_it_launches_is_an_executable_of_the_package(launch_file: dict[str, Any]) -> None:
    for layout in LAYOUTS:
        nodes = launched(launch_file, **layout)
        assert nodes, layout
        for node in nodes:
            assert node["package"] == "stereo_depth", node
            assert node["executable"] in console_scripts(), f"{node['executable']} ({layout}): no such console script"


def changed(name: str, default: str) -> str:
    """Another value for the argument `name`: the other boolean, another profile, a path, a namespace."""
    if default.lower() in ("true", "false"):
        return "false" if default.lower() == "true" else "true"
    if name == "profile":
        return next(p for p in PROFILES if p != default)
    return "/elsewhere/params.yaml" if name == "params_file" else f"/elsewhere/{default}".rstrip("/")


def test_every_argument_it_documents_changes_what_is_launched(launch_file: dict[str, Any]) -> None:
    """Declared arguments, and those the docstring's examples pass (`name:=`): each one changes the nodes
    or their parameters or remaps in some layout (an argument read and ignored would pass a 'read' check)."""
    arguments = declared(launch_file)
    in_examples = set(re.findall(r"(\w+):=", launch_file["__doc__"]))
    assert in_examples <= arguments.defaults.keys(), in_examples - arguments.defaults.keys()
    for name, default in arguments.defaults.items():
        differs = [
            layout
            for layout in LAYOUTS
            if layout.get(name, default) == default
            and launched(launch_file, **layout) != launched(launch_file, **{**layout, name: changed(name, default)})
        ]
        assert differs, f"the argument {name} changes nothing in any layout"


def test_the_profile_argument_names_every_profile_the_nodes_know(launch_file: dict[str, Any]) -> None:
    description = declared(launch_file).descriptions["profile"]
    named = set(re.findall(r"\w+", description.split(":", 1)[1]))
    assert named == set(PROFILES), description


@pytest.fixture(scope="module")
def topics(
    ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[dict[str, set[str]]]:
    """Each node executable the launch file names, running under NS: the topics it subscribes and publishes,
    relative to its namespace, as `ros2 node info` lists them."""
    executables = ("stereo_node", "rectify_node", "disparity_node", "point_cloud_node")
    logs = tmp_path_factory.mktemp("launch_nodes")
    odometry = ["-p", "left_in_base:=[0.0, 0.0, 0.2, -0.5, 0.5, -0.5, 0.5]"]  # the odom input too
    registering = ["-p", "rgb_in_left:=[0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]", *odometry]  # the colour inputs too
    args = {"stereo_node": registering, "disparity_node": odometry}
    processes = [NodeProcess(executable, NS, ros_env, logs, args.get(executable, ())) for executable in executables]
    with ros.running(processes):
        yield {process.name: node_topics(ros, process) for process in processes}


def node_topics(ros: RosHarness, process: NodeProcess) -> set[str]:
    """Once the node is ready (its inputs, created last, and its diagnostics output in the graph)."""
    ready = wait_until(lambda: re.search(r"ready: inputs (.*)", process.output()), f"{process.fqn} ready")
    expected = {topic.removeprefix(f"{NS}/") for topic in ready[1].split(", ")} | {"diagnostics"}

    def seen() -> set[str]:
        endpoints = [
            *ros.node.get_subscriber_names_and_types_by_node(process.name, NS),
            *ros.node.get_publisher_names_and_types_by_node(process.name, NS),
        ]
        return {topic.removeprefix(f"{NS}/") for topic, _ in endpoints}

    found: set[str] = wait_until(lambda: expected <= seen() and seen(), f"{process.fqn}'s topics in the graph")
    return found


def test_every_remap_renames_a_topic_of_its_node(launch_file: dict[str, Any], topics: dict[str, set[str]]) -> None:
    """A remap naming no topic of its node does nothing, silently: the camera's topics it meant to
    connect stay apart."""
    cameras = {"left_namespace": "/camera/left", "right_namespace": "/camera/right", "rgb_namespace": "/camera/color"}
    for layout in LAYOUTS:
        nodes = launched(launch_file, **layout, **cameras)
        for node in nodes:
            known = topics[node["executable"]]
            for source, _ in node["remappings"]:
                assert source in known, f"{node['name']} ({layout}): remaps {source}, not one of {sorted(known)}"
