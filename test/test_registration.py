"""Depth registered to a colour camera: the projection (the nearest surface wins, one-pixel cracks close,
what the depth camera could not see stays invalid), the pose composed with both cameras' rectification,
the pairing by stamp, a Kalibr cam2, and `process` with its bad inputs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from colour_bag import CAMCHAIN, NS, cam1_in_cam0, colour_info, write_colour_bag

from stereo_depth.bag.reader import read_messages
from stereo_depth.bag.types import rosbags_types
from stereo_depth.cli import main
from stereo_depth.core.camera import CameraInfo
from stereo_depth.core.pose import Pose
from stereo_depth.core.registration import PinholeModel, RigidMotion, left_rectified_to_colour, register_depth
from stereo_depth.errors import ParameterError
from stereo_depth.formats.kalibr import read_camchain_colour
from stereo_depth.frames.registered import colour_calibration, undistorted_model
from stereo_depth.messages import camera_info_to_msg, make_header
from stereo_depth.nearest_sync import NearestPairing
from stereo_depth.options import output_options

CAMERA = PinholeModel(64, 48, 50.0, 50.0, 31.5, 23.5)
STILL = np.eye(3)


def beside(x: float) -> RigidMotion:
    """A colour camera `x` metres to the right of the depth camera, looking the same way."""
    return RigidMotion(STILL, np.array([-x, 0.0, 0.0]))


def registered(depth: np.ndarray, motion: RigidMotion, target: PinholeModel = CAMERA) -> np.ndarray:
    return register_depth(depth.astype(np.float32), CAMERA.rays(), motion, target)


def test_a_plane_seen_from_beside_keeps_its_depth_shifted_by_its_disparity() -> None:
    plane = np.full((48, 64), 2.0)
    out = registered(plane, beside(0.1))  # shifts 50 * 0.1 / 2 = 2.5 px to the left
    assert np.all(out[:, :58] == np.float32(2.0))
    assert np.isnan(out[:, 62:]).all()  # beyond the depth camera's view


def test_the_nearest_surface_wins_and_what_only_the_colour_camera_sees_stays_invalid() -> None:
    scene = np.full((48, 64), 4.0)
    scene[:, 30:40] = 1.0  # a post 1 m away in front of a wall 4 m away
    out = registered(scene, beside(0.2))  # the post shifts 10 px, the wall 2.5 px
    assert np.all(out[:, 21:29] == np.float32(1.0))  # the wall's pixels that land there lose
    assert np.isnan(out[:, 31:36]).all()  # wall the post hid from the depth camera: not made up
    assert np.all(out[:, 40:60] == np.float32(4.0))


def test_one_pixel_cracks_of_a_finer_colour_camera_close() -> None:
    finer = PinholeModel(96, 72, 75.0, 75.0, 47.5, 35.5)  # 1.5x the depth's resolution: every other pixel a crack
    out = registered(np.full((48, 64), 3.0), RigidMotion(STILL, np.zeros(3)), finer)
    assert np.all(out[2:-2, 2:-2] == np.float32(3.0))


def test_the_pose_is_composed_with_each_cameras_rectification() -> None:
    """A point given in the colour camera's frame, moved to the left camera's raw frame by the pose and
    rectified, comes back to the colour camera's rectified frame."""
    pose = Pose.from_list([0.05, -0.01, 0.02, math.sin(0.1), 0.0, 0.0, math.cos(0.1)])
    left_r = Pose.from_list([0, 0, 0, 0.0, math.sin(0.02), 0.0, math.cos(0.02)]).rotation_matrix()
    colour_r = Pose.from_list([0, 0, 0, 0.0, 0.0, math.sin(0.03), math.cos(0.03)]).rotation_matrix()
    point = np.array([0.3, -0.2, 2.5])
    in_left_rectified = left_r @ pose.apply(point)
    motion = left_rectified_to_colour(pose, left_r, colour_r)
    assert np.allclose(motion.rotation @ in_left_rectified + motion.translation, colour_r @ point)


def pairs_of(stereo: list[int], colour: list[int], order: str, tolerance: int = 16) -> list[tuple[int, int]]:
    pairing: NearestPairing[int, int] = NearestPairing(tolerance)
    events = sorted([(s, 0, s) for s in stereo] + [(c, 1, c) for c in colour])
    if order == "colour late":  # the colour images arrive three stereo frames after their time
        events = sorted([(s, 0, s) for s in stereo] + [(c + 150, 1, c) for c in colour])
    found = []
    for _, kind, stamp in events:
        if kind:
            pairing.add_extra(stamp, stamp)
        else:
            found += [(p.primary_ns, p.extra_ns) for p in pairing.add_primary(stamp, stamp)]
    return found + [(p.primary_ns, p.extra_ns) for p in pairing.flush()]


def test_a_colour_image_pairs_with_the_nearest_stereo_set_whatever_arrives_first() -> None:
    stereo = list(range(0, 1000, 50))  # 20 Hz
    colour = list(range(7, 1000, 33))  # 30 Hz, unsynchronised
    in_time = pairs_of(stereo, colour, "in time")
    assert in_time == pairs_of(stereo, colour, "colour late")
    for stereo_ns, colour_ns in in_time:
        assert abs(stereo_ns - colour_ns) <= 16
        assert all(abs(s - colour_ns) >= abs(stereo_ns - colour_ns) for s in stereo)
    assert len(in_time) == sum(any(abs(s - c) <= 16 for s in stereo) for c in colour)


def test_stereo_sets_without_a_colour_image_are_counted_and_the_stereo_goes_on() -> None:
    pairing: NearestPairing[int, int] = NearestPairing(16)
    for stamp in range(0, 500, 50):  # the colour camera stopped after the first frames
        if stamp < 100:
            pairing.add_extra(stamp + 3, stamp)
        pairing.add_primary(stamp, stamp)
    pairing.flush()
    assert pairing.counters.paired == 2
    assert pairing.counters.unpaired_primary == 8


def test_an_unnormalised_quaternion_is_refused_with_the_reason() -> None:
    with pytest.raises(ParameterError, match=r"rgb_in_left: quaternion .* has norm 2.0000"):
        output_options({"rgb_in_left": [0.1, 0, 0, 0, 0, 0, 2.0]})


# ---------------------------------------------------------------- Kalibr cam2

CAM2_IN_CAM0 = [0.15, 0.01, -0.02, 0.0, math.sin(0.025), 0.0, math.cos(0.025)]


def camchain_with_cam2(path: Path) -> Path:
    """The bundled camchain plus cam2: cam1's intrinsics, placed at CAM2_IN_CAM0 (written as Kalibr does:
    T_cn_cnm1 maps points from cam1 into cam2)."""
    document = yaml.safe_load(CAMCHAIN.read_text())
    t_10 = np.asarray(document["cam1"]["T_cn_cnm1"])
    pose = Pose.from_list(CAM2_IN_CAM0)
    t_02 = np.eye(4)
    t_02[:3, :3], t_02[:3, 3] = pose.rotation_matrix(), pose.translation
    document["cam2"] = {**document["cam1"], "T_cn_cnm1": (np.linalg.inv(t_02) @ np.linalg.inv(t_10)).tolist()}
    path.write_text(yaml.safe_dump(document))
    return path


def test_a_camchain_cam2_is_chained_onto_cam1_and_inverted(tmp_path: Path) -> None:
    colour = read_camchain_colour(camchain_with_cam2(tmp_path / "camchain.yaml"))
    assert colour is not None
    info, pose = colour
    assert np.allclose(pose.as_list(), CAM2_IN_CAM0, atol=1e-12)
    assert np.allclose(info.p[:, :3], colour_info().k) and not np.any(info.p[:, 3])
    assert read_camchain_colour(CAMCHAIN) is None


def registered_depths(out: Path) -> list[np.ndarray]:
    messages = read_messages(out, [f"{NS}/depth_registered/image_rect"])[f"{NS}/depth_registered/image_rect"]
    return [np.frombuffer(bytes(m.data), np.float32).reshape(m.height, m.width) for m in messages]


def test_a_camchain_with_cam2_registers_as_the_equal_rgb_in_left(tmp_path: Path) -> None:
    bag = tmp_path / "colour"
    write_colour_bag(bag, 3)  # its rgb/camera_info: cam1's intrinsics, as cam2's
    outputs = ["--outputs", "depth_registered/image_rect"]
    chain = camchain_with_cam2(tmp_path / "camchain.yaml")
    assert main(["process", str(bag), str(tmp_path / "chain"), "--camera-info", str(chain), *outputs]) == 0
    pose = f"rgb_in_left={CAM2_IN_CAM0}"
    given = ["--camera-info", str(CAMCHAIN), "--set", pose, *outputs]  # stereo from the camchain, colour from the bag
    assert main(["process", str(bag), str(tmp_path / "given"), *given]) == 0
    from_chain, from_pose = registered_depths(tmp_path / "chain"), registered_depths(tmp_path / "given")
    assert len(from_chain) == len(from_pose) == 3
    for a, b in zip(from_chain, from_pose, strict=True):
        assert np.isfinite(a).mean() > 0.7
        assert np.array_equal(np.isnan(a), np.isnan(b))
        assert np.nanmax(np.abs(a - b)) < 1e-5


# ---------------------------------------------------------------- process: bad input


def test_a_registered_output_without_rgb_in_left_exits_1_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "colour"
    write_colour_bag(bag, 2)
    out = tmp_path / "out"
    assert main(["process", str(bag), str(out), "--outputs", "depth_registered/image_rect"]) == 1
    assert "set rgb_in_left" in capsys.readouterr().err
    assert not out.exists()


def test_a_bag_without_a_colour_camera_exits_1_naming_the_flags(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"
    given = ["--set", f"rgb_in_left={cam1_in_cam0()}", "--outputs", "depth", "depth_registered/points"]
    assert main(["process", str(bag), str(tmp_path / "out"), *given]) == 1
    assert "no image under /stereo/rgb/" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_colour_camera_info_without_focal_length_skips_only_the_registered_outputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "uncalibrated"
    zero = np.zeros((3, 3))
    write_colour_bag(bag, 3, colour=CameraInfo.from_values(752, 480, zero, [], zero, np.zeros((3, 4))))
    given = ["--set", f"rgb_in_left={cam1_in_cam0()}", "--outputs", "depth", "depth_registered/image_rect"]
    assert main(["process", str(bag), str(tmp_path / "out"), *given]) == 0
    printed = capsys.readouterr().out
    assert f"skipped 3x: {NS}/rgb/camera_info: no focal length" in printed
    assert len(read_messages(tmp_path / "out", [f"{NS}/depth"])[f"{NS}/depth"]) == 3


def test_a_rectified_colour_camera_info_with_only_p_is_accepted() -> None:
    p = np.array([[500.0, 0.0, 320.0, 0.0], [0.0, 500.0, 240.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    info = colour_calibration(camera_info_to_msg(rosbags_types(), make_header(rosbags_types(), 1, "rgb"), colour_of(p)))
    assert np.array_equal(info.k, p[:, :3]) and not np.any(info.d)
    assert undistorted_model(info, "rgb").p.tolist() == p.tolist()


def colour_of(p: np.ndarray) -> CameraInfo:
    """A camera_info of a rectified image that holds only P (K, D and R empty), as some drivers publish."""
    return CameraInfo.from_values(640, 480, np.zeros((3, 3)), [], np.zeros((3, 3)), p)


def test_a_colour_camera_that_stops_shows_in_diagnostics() -> None:
    from std_msgs.msg import Header

    from stereo_depth.ros.diagnostics import NodeDiagnostics

    stereo = [f"{NS}/left/image_raw", f"{NS}/right/image_raw"]
    colour = [f"{NS}/rgb/image_raw", f"{NS}/rgb/camera_info"]
    diagnostics = NodeDiagnostics("/stereo_node", [*stereo, *colour])
    for topic in stereo:
        diagnostics.input_received(topic, 1)
    diagnostics.registration(12)
    status = diagnostics.report(Header()).status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert f"{NS}/rgb/image_raw (never)" in status.message
    assert values["frames without a colour image (registered outputs)"] == "12"
