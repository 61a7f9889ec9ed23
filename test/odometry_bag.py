"""A bag of a robot whose stereo camera pitches (plus and minus 2 degrees, 1.2 s period, 30 Hz) with the
odometry that describes it (nav_msgs/Odometry at 100 Hz, stamped as recorded), made from a real scene.

The camera turns about its baseline, so both rectified images of the scene move by one homography
(H = K R^T K^-1) and stay rectified; each frame has fresh sensor noise. The camera looks forward from the
robot's base (`LEFT_IN_BASE`, REP 103 optical axes), and the base turns with it, so the odometry's pose is
the camera's turn seen from the base."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from stereo_depth.bag.types import rosbags_types, typestore
from stereo_depth.bag.writer import BagWriter
from stereo_depth.core.camera import CameraInfo
from stereo_depth.core.pose import Pose
from stereo_depth.formats.scenes import load_scene
from stereo_depth.messages import array_to_image, camera_info_to_msg, make_header

from conftest import SCENES

NS = "/stereo"
ODOM = f"{NS}/odom"
STEREO_TOPICS = tuple(f"{NS}/{side}/{kind}" for side in ("left", "right") for kind in ("image_raw", "camera_info"))
START_NS = 1_700_000_000_000_000_000
FRAME_NS = 33_333_333  # 30 Hz
ODOM_NS = 10_000_000  # 100 Hz
PITCH_RADIANS = np.radians(2.0)
PITCH_PERIOD_S = 1.2
BASELINE_M = 0.1
# the left optical frame (x right, y down, z forward) on a base (x forward, y left, z up), 0.2 m up
LEFT_IN_BASE = [0.1, 0.0, 0.2, -0.5, 0.5, -0.5, 0.5]
NOISE_SIGMA = 2.0


def left_in_base_text() -> str:
    return "[" + ", ".join(str(v) for v in LEFT_IN_BASE) + "]"


def left_in_base_matrix() -> np.ndarray:
    return Pose.from_list(LEFT_IN_BASE).matrix()


def pitch(t_s: float) -> tuple[float, float]:
    """The camera's pitch (radians, about its x axis) at `t_s` after the start, and its rate (rad/s)."""
    phase = 2.0 * np.pi * t_s / PITCH_PERIOD_S
    return PITCH_RADIANS * np.sin(phase), PITCH_RADIANS * 2.0 * np.pi / PITCH_PERIOD_S * np.cos(phase)


def about_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def camera_infos(width: int, height: int) -> tuple[CameraInfo, CameraInfo]:
    """A rectified pair: focal length the image width, principal point the centre, R = I."""
    f = float(width)
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    left_p = np.hstack([k, np.zeros((3, 1))])
    right_p = left_p.copy()
    right_p[0, 3] = -f * BASELINE_M
    return (
        CameraInfo.from_values(width, height, k, np.zeros(5), np.eye(3), left_p, "plumb_bob", "left_optical"),
        CameraInfo.from_values(width, height, k, np.zeros(5), np.eye(3), right_p, "plumb_bob", "right_optical"),
    )


def odometry_message(stamp_ns: int, shift_m: float = 0.0) -> Any:
    """The base's pose and twist at `stamp_ns`: the camera's pitch as the base sees it (the base starts at
    the odometry frame's origin; `shift_m` moves the odometry frame along x, as a relocalisation does)."""
    types = typestore().types
    angle, rate = pitch((stamp_ns - START_NS) * 1e-9)
    camera = left_in_base_matrix()
    turned = np.eye(4)
    turned[:3, :3] = about_x(angle)
    base = camera @ turned @ np.linalg.inv(camera)
    x, y, z, w = quaternion(base[:3, :3])
    angular = camera[:3, :3] @ np.array([rate, 0.0, 0.0])  # the turn's rate, in the base frame
    point, vector = types["geometry_msgs/msg/Point"], types["geometry_msgs/msg/Vector3"]
    pose = types["geometry_msgs/msg/Pose"](
        position=point(x=float(base[0, 3]) + shift_m, y=float(base[1, 3]), z=float(base[2, 3])),
        orientation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
    )
    twist = types["geometry_msgs/msg/Twist"](
        linear=vector(x=0.0, y=0.0, z=0.0), angular=vector(x=angular[0], y=angular[1], z=angular[2])
    )
    return types["nav_msgs/msg/Odometry"](
        header=make_header(rosbags_types(), stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix whose angle is below a half turn."""
    w = np.sqrt(max(0.0, 1.0 + np.trace(rotation))) / 2.0
    x = (rotation[2, 1] - rotation[1, 2]) / (4.0 * w)
    y = (rotation[0, 2] - rotation[2, 0]) / (4.0 * w)
    z = (rotation[1, 0] - rotation[0, 1]) / (4.0 * w)
    return float(x), float(y), float(z), float(w)


def write_odometry_bag(
    out: Path,
    frames: int = 30,
    *,
    odometry_until_s: float | None = None,
    jump_at_s: float | None = None,
    with_odometry: bool = True,
) -> list[int]:
    """The bag (tsukuba, grey); returns the frame stamps. `odometry_until_s`: the odometry stops after
    this many seconds (None: it covers every frame); `jump_at_s`: from then on its poses are 1 m off (a
    relocalisation); `with_odometry` False: no odometry topic."""
    scene = load_scene(SCENES / "tsukuba")
    left, right = (cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in (scene.left, scene.right))
    height, width = left.shape
    infos = camera_infos(width, height)
    k = infos[0].k
    rng = np.random.default_rng(1)
    types = rosbags_types()
    stamps = [START_NS + index * FRAME_NS for index in range(frames)]
    odometry = range(START_NS - 5 * ODOM_NS, stamps[-1] + 5 * ODOM_NS + 1, ODOM_NS) if with_odometry else range(0)
    if odometry_until_s is not None:
        odometry = range(odometry.start, START_NS + round(odometry_until_s * 1e9), ODOM_NS)
    jump_ns = None if jump_at_s is None else START_NS + round(jump_at_s * 1e9)
    records: list[tuple[int, str, Any]] = [
        (stamp, ODOM, odometry_message(stamp, 1.0 if jump_ns is not None and stamp >= jump_ns else 0.0))
        for stamp in odometry
    ]
    for stamp in stamps:
        h = k @ about_x(pitch((stamp - START_NS) * 1e-9)[0]).T @ np.linalg.inv(k)
        for side, image, info in (("left", left, infos[0]), ("right", right, infos[1])):
            moved = cv2.warpPerspective(
                image, h, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            )
            noisy = np.clip(np.rint(moved + rng.normal(0.0, NOISE_SIGMA, moved.shape)), 0, 255).astype(np.uint8)
            header = make_header(types, stamp, info.frame_id)
            records.append((stamp, f"{NS}/{side}/image_raw", array_to_image(types, header, noisy, "mono8")))
            records.append((stamp, f"{NS}/{side}/camera_info", camera_info_to_msg(types, header, info)))
    with BagWriter(out, compress=False) as writer:
        for stamp, topic, message in sorted(records, key=lambda record: record[0]):
            writer.write(topic, message, stamp)
    return stamps
