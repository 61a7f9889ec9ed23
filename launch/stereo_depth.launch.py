"""Launch stereo_depth on a stereo camera's topics (needs a full ROS 2 install: launch, launch_ros).

    ros2 launch stereo_depth stereo_depth.launch.py namespace:=stereo \
        left_namespace:=/camera/left right_namespace:=/camera/right params_file:=/path/params.yaml
    ros2 launch stereo_depth stereo_depth.launch.py split_nodes:=true   # stereo_image_proc's layout
    ros2 launch stereo_depth stereo_depth.launch.py rgb_namespace:=/camera/color params_file:=/path/rgbd.yaml
    ros2 launch stereo_depth stereo_depth.launch.py odom:=/odometry/filtered params_file:=/path/robot.yaml

With rgb_in_left set (in the params_file), stereo_node reads the colour camera under `rgb_namespace` and
publishes depth registered to it (docs/rgbd.md). With left_in_base set (in the params_file) and
temporal_filter on, stereo_node (disparity_node with split_nodes) reads the robot's odometry from `odom`
and the temporal filter moves its history with the camera (docs/navigation.md).

Defaults live in the nodes (declared once, from the dataclasses), so nothing is restated here.
`profile` picks the defaults; a `params_file` (config/stereo_depth.yaml lists every parameter) wins
over the profile for each value it sets.
"""

from __future__ import annotations

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchContext, LaunchDescription
from stereo_depth.core.params import PROFILES

PACKAGE = "stereo_depth"
ARGUMENTS = {
    "namespace": ("", "Namespace of the nodes and their outputs"),
    "left_namespace": ("left", "Topic namespace of the left camera (image_raw, camera_info)"),
    "right_namespace": ("right", "Topic namespace of the right camera"),
    "rgb_namespace": (
        "rgb",
        "Topic namespace of the colour camera (image_raw, camera_info), read with rgb_in_left set",
    ),
    "odom": (
        "odom",
        "The robot's nav_msgs/Odometry topic (e.g. /odom, /odometry/filtered), read with left_in_base set",
    ),
    "params_file": ("", "Parameter YAML (e.g. config/stereo_depth.yaml); empty: the profile's defaults"),
    "profile": ("default", f"Named defaults: {', '.join(PROFILES)}"),
    "split_nodes": ("false", "true: rectify_node x2 -> disparity_node -> point_cloud_node"),
    "color": ("false", "split_nodes only: the left camera is colour, so the cloud takes image_rect_color"),
}


def _nodes(context: LaunchContext) -> list[Node]:
    arg = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    parameters: list[object] = [{"profile": arg["profile"]}]
    if arg["params_file"]:
        parameters.insert(0, arg["params_file"])
    cameras = {"left": arg["left_namespace"].rstrip("/"), "right": arg["right_namespace"].rstrip("/")}
    colour = arg["rgb_namespace"].rstrip("/")
    odometry = ("odom", arg["odom"])  # with left_in_base

    def to_cameras(*names: str, sides: tuple[str, ...] = ("left", "right")) -> list[tuple[str, str]]:
        """A node's `<side>/<name>` topics renamed to the camera's own `<camera namespace>/<name>`."""
        return [(f"{side}/{name}", f"{cameras[side]}/{name}") for side in sides for name in names]

    common = {"package": PACKAGE, "namespace": arg["namespace"], "parameters": parameters}
    if arg["split_nodes"].lower() != "true":
        remaps = [
            *to_cameras("image_raw", "camera_info"),
            *to_cameras("image_rect", "image_rect_color"),  # both: what stereo odometry subscribes
            *((f"rgb/{name}", f"{colour}/{name}") for name in ("image_raw", "camera_info")),  # with rgb_in_left
            odometry,
        ]
        return [Node(executable="stereo_node", name="stereo_node", remappings=remaps, **common)]
    cloud_image = "image_rect_color" if arg["color"].lower() == "true" else "image_rect"
    rectifiers = [
        Node(
            executable="rectify_node",
            name=f"rectify_{side}",
            remappings=[
                ("image", f"{ns}/image_raw"),
                ("camera_info", f"{ns}/camera_info"),
                ("image_rect", f"{ns}/image_rect"),
            ],
            **common,
        )
        for side, ns in cameras.items()
    ]
    return [
        *rectifiers,
        Node(
            executable="disparity_node",
            name="disparity_node",
            remappings=[*to_cameras("image_rect", "camera_info"), odometry],
            **common,
        ),
        Node(
            executable="point_cloud_node",
            name="point_cloud_node",
            remappings=[("left/image_rect_color", f"{cameras['left']}/{cloud_image}"), *to_cameras("camera_info")],
            **common,
        ),
    ]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            *(
                DeclareLaunchArgument(name, default_value=default, description=text)
                for name, (default, text) in ARGUMENTS.items()
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
