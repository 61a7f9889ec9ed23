"""List-valued options and pose options, through the paths users take: `process --set` and `--params`,
the generated YAML and parameters page, and a node's parameters set over its parameter service.

The output options gain a pose and a list of their own here (a subclass put in place of OutputOptions where
the commands, the nodes' parameters and the documents read it), apart from the shipped ones.
"""

from __future__ import annotations

import argparse
import math
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import yaml

from stereo_depth import options, options_docs
from stereo_depth.cli import build_parser, main
from stereo_depth.commands import process as process_command
from stereo_depth.commands.common import add_option_flags, assignments
from stereo_depth.core.option_fields import coerced, option, pose_option
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pose import UNSET_POSE, Pose
from stereo_depth.options import NodeOptions, OutputOptions, Settings

MIDDLEBURY_BAG = Path(__file__).resolve().parents[1] / "bags" / "middlebury"
HALF = math.sqrt(0.5)


@dataclass(frozen=True)
class PosedOutputs(OutputOptions):
    camera_in_left: Pose = pose_option("A camera's optical frame in the left camera's optical frame")
    gains: tuple[float, ...] = option((1.0, 2.0, 3.0), "Three gains", 0.0, 10.0, length=3)


@pytest.fixture
def posed(monkeypatch: pytest.MonkeyPatch) -> None:
    """The output options with a pose and a list, wherever the commands and documents read them."""
    for module in (options, process_command, options_docs):
        monkeypatch.setattr(module, "OutputOptions", PosedOutputs)
    monkeypatch.setattr(options_docs, "SECTIONS", (("outputs", PosedOutputs),))
    monkeypatch.setattr(options, "OPTION_CLASSES", (StereoParams, PosedOutputs, NodeOptions))  # known names


def settings(*extra: str) -> Settings:
    args = build_parser().parse_args(["process", str(MIDDLEBURY_BAG), "out", *extra])
    return process_command.settings_from(args)[1]


def outputs(*extra: str) -> PosedOutputs:
    output = settings(*extra).output
    assert isinstance(output, PosedOutputs)
    return output


@pytest.mark.usefixtures("posed")
def test_set_reads_a_list_as_yaml_and_takes_integers_where_doubles_are_declared() -> None:
    output = outputs("--set", "camera_in_left=[0.1, 0, 0, 0, 0, 0, 1]", "--set", "gains=[4, 5, 6]")
    assert output.camera_in_left == Pose((0.1, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)) and output.camera_in_left.is_set
    assert output.gains == (4.0, 5.0, 6.0) and all(isinstance(g, float) for g in output.gains)


@pytest.mark.usefixtures("posed")
def test_set_reads_yaml_only_for_list_options() -> None:
    given = assignments(["mask_image=[robot].png", "gains=[1, 2, 3]"])
    assert given == {"mask_image": "[robot].png", "gains": [1, 2, 3]}


@pytest.mark.usefixtures("posed")
def test_a_pose_is_unset_by_default_and_seven_zeros_say_unset() -> None:
    assert outputs().camera_in_left == UNSET_POSE and not outputs().camera_in_left.is_set
    assert not outputs("--set", "camera_in_left=[0, 0, 0, 0, 0, 0, 0]").camera_in_left.is_set


@pytest.mark.usefixtures("posed")
def test_a_parameter_file_gives_lists_as_ros_reads_them(tmp_path: Path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(
        "/**:\n  ros__parameters:\n"
        f"    camera_in_left: [0.0, 0.0, 0.5, 0.0, 0.0, {HALF}, {HALF}]\n"
        "    gains: [1e-3, 2, 3]\n"  # PyYAML reads 1e-3 as text, ROS as a double
    )
    output = outputs("--params", str(params), "--set", "gains=[7, 8, 9]")
    assert output.camera_in_left.translation == (0.0, 0.0, 0.5)
    assert output.camera_in_left.rotation_matrix() @ [1, 0, 0] == pytest.approx([0, 1, 0])
    assert output.gains == (7.0, 8.0, 9.0)  # --set wins
    assert outputs("--params", str(params)).gains == (0.001, 2.0, 3.0)


@pytest.mark.usefixtures("posed")
@pytest.mark.parametrize(
    ("assignment", "reason"),
    [
        (
            "camera_in_left=[0, 0, 0, 0, 0, 0, 2]",
            "camera_in_left: quaternion (0, 0, 0, 2) has norm 2.0000; give a unit quaternion (x, y, z, w)",
        ),
        ("camera_in_left=[1, 0, 0, 0, 0, 0, 0]", "camera_in_left: quaternion (0, 0, 0, 0) has norm 0.0000"),
        ("camera_in_left=[0, 0, 1]", "camera_in_left: [0, 0, 1] has 3 values; give a pose [x, y, z, qx, qy, qz, qw]"),
        ("gains=[1, 2, 30]", "gains [1.0, 2.0, 30.0]: 30.0 is outside [0.0, 10.0]"),
        ("gains=[1, 2, -0.5]", "gains [1.0, 2.0, -0.5]: -0.5 is outside [0.0, 10.0]"),
        ("gains=[1, 2, x]", "gains: [1, 2, 'x'] is not a list of 3 numbers"),
        ("gains=[1, 2, .nan]", "gains: [1, 2, nan] is not a list of 3 numbers"),
        ("gains=2", "gains: 2 is not a list of 3 numbers, e.g. [0.0, 0.0, 0.0]"),
        ("gains=[1, 2", "gains: cannot read '[1, 2' as a YAML list"),
    ],
)
def test_process_refuses_a_bad_list_with_the_reason_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], assignment: str, reason: str
) -> None:
    out = tmp_path / "out"
    assert main(["process", str(MIDDLEBURY_BAG), str(out), "--set", assignment]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"ERROR: {reason}" in err
    assert not out.exists()


def test_a_list_option_flag_reads_yaml_as_set_does() -> None:
    parser = argparse.ArgumentParser()
    add_option_flags(parser, PosedOutputs, ("gains", "camera_in_left"))
    args = parser.parse_args(["--gains", "[1, 2, 3]", "--camera-in-left", "[0, 0, 1, 0, 0, 0, 1]"])
    given = coerced(PosedOutputs, vars(args))
    assert given["gains"] == (1.0, 2.0, 3.0) and given["camera_in_left"].translation == (0.0, 0.0, 1.0)


@pytest.mark.usefixtures("posed")
def test_the_config_yaml_and_parameters_page_render_lists_of_doubles() -> None:
    text = options_docs.render_config_yaml()
    assert "    # Three gains [0.0 .. 10.0 each]\n    gains: [1.0, 2.0, 3.0]\n" in text
    values = yaml.safe_load(text)["/**"]["ros__parameters"]
    assert values["camera_in_left"] == [0.0] * 7 and all(type(v) is float for v in values["camera_in_left"])
    rows = "\n".join(options_docs._parameters(SimpleNamespace(OPTIONS=("camera_in_left", "gains"), WITH_STEREO=False)))
    assert (
        "| `camera_in_left` | pose | `[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]` | x, y, z (m), qx, qy, qz, qw (unit "
        "quaternion); all zero: unset | dynamic |"
    ) in rows
    assert "| `gains` | float[3] | `[1.0, 2.0, 3.0]` | 0 .. 10 each | dynamic | Three gains. |" in rows


# ------------------------------------------------------------------------------------- a node's parameters


@pytest.fixture
def posed_node(ros: Any, posed: None, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Any, list[Settings]]]:
    """A node declaring the two options through the nodes' parameter code, started with `-p` integers for the
    pose, served by its own executor; `ros` sets its parameters as `ros2 param set` does."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from stereo_depth.ros import parameters

    monkeypatch.setattr(parameters, "OutputOptions", PosedOutputs)
    node = Node("posed_params", parameter_overrides=[Parameter("camera_in_left", value=[0, 0, 1, 0, 0, 0, 1])])
    applied: list[Settings] = []
    parameters.NodeParameters(node, ("camera_in_left", "gains"), with_stereo=False, on_change=applied.append)
    described = node.describe_parameter("camera_in_left")
    assert described.type == ParameterType.PARAMETER_DOUBLE_ARRAY and "qw (a unit quaternion)" in (
        described.additional_constraints
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinning = threading.Thread(target=executor.spin, daemon=True)
    spinning.start()
    yield node, applied
    executor.shutdown()
    spinning.join()
    node.destroy_node()


def latest(applied: list[Settings]) -> PosedOutputs:
    output = applied[-1].output
    assert isinstance(output, PosedOutputs)
    return output


def test_ros_param_set_takes_a_pose_and_refuses_a_bad_one_with_the_reason(
    ros: Any, posed_node: tuple[Any, list[Settings]]
) -> None:
    node, applied = posed_node
    assert node.get_parameter("camera_in_left").value == [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # -p gave integers
    fqn = node.get_fully_qualified_name()
    [ok] = ros.set_parameters(fqn, camera_in_left=[0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    assert ok.successful
    assert latest(applied).camera_in_left == Pose((0.2, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    [integers] = ros.set_parameters(fqn, gains=[4, 5, 6])
    assert integers.successful and latest(applied).gains == (4.0, 5.0, 6.0)
    [mixed] = ros.set_parameters(fqn, camera_in_left="[0.3, 0, 0, 0, 0, 0, 1]")  # ros2 param set sends it as text
    assert mixed.successful and latest(applied).camera_in_left.translation == (0.3, 0.0, 0.0)
    [word] = ros.set_parameters(fqn, gains="high")
    assert not word.successful and "expected 'Type.DOUBLE_ARRAY' got 'Type.STRING'" in word.reason
    [bad] = ros.set_parameters(fqn, camera_in_left=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
    assert not bad.successful
    assert bad.reason == "camera_in_left: quaternion (0, 0, 0, 2) has norm 2.0000; give a unit quaternion (x, y, z, w)"
    [short] = ros.set_parameters(fqn, camera_in_left=[0.0, 0.0, 1.0])
    assert not short.successful and "has 3 values" in short.reason
    [outside] = ros.set_parameters(fqn, gains=[1.0, 2.0, 30.0])
    assert not outside.successful and outside.reason == "gains [1.0, 2.0, 30.0]: 30.0 is outside [0.0, 10.0]"
    values = ros.get_parameters(fqn, "camera_in_left", "gains")
    assert {name: list(value) for name, value in values.items()} == {
        "camera_in_left": [0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        "gains": [4.0, 5.0, 6.0],
    }
    assert len(applied) == 3
