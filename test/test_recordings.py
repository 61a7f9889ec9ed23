"""Real recordings as datasets and robots store them: ROS 1 bags, compressed images, calibration in files,
topic names from the wild. The bundled EuRoC frames are written each way (into tmp_path) and processed;
the same frames as a ROS 2 raw bag are the reference."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from stereo_depth.bag.make import StreamLayout, write_stream
from stereo_depth.bag.process import ProcessOptions, process_bag
from stereo_depth.bag.reader import TopicChoice, find_stereo_topics, read_messages
from stereo_depth.bag.sources import read_frames
from stereo_depth.bag.types import rosbags_types
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.commands.check_calibration import check_bag, overall
from stereo_depth.core.calibration_check import Level
from stereo_depth.core.params import make_params
from stereo_depth.errors import BagError, CalibrationError, ImageError
from stereo_depth.formats.calibration_files import read_stereo_calibration
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.messages import (
    array_to_compressed,
    compressed_format,
    compressed_to_pipeline,
    disparity_from_msg,
    make_header,
    stamp_to_ns,
)

from conftest import EUROC, assert_same_calibration

CAMCHAIN = EUROC / "camchain.yaml"


def layout(**fields: Any) -> StreamLayout:
    """The bundled frames' stream with the frame ids of bags/euroc_raw."""
    return StreamLayout(left_frame_id="cam0", right_frame_id="cam1", **fields)


EUROC_LAYOUT = layout(
    namespace="/", overrides={"left_image": "/cam0/image_raw", "right_image": "/cam1/image_raw"}, camera_info=False
)
Disparities = dict[int, np.ndarray]


def write_bag(path: Path, layout: StreamLayout, storage: str = "mcap") -> Path:
    with BagWriter(path, storage=storage) as writer:
        write_stream(read_frames([EUROC]), writer, layout)
    return path


def disparities(bag: Path, topic: str) -> Disparities:
    messages = read_messages(bag, [topic])[topic]
    return {stamp_to_ns(m.header.stamp): disparity_from_msg(m) for m in messages}


def processed(bag: Path, out: Path, *options: str) -> Path:
    assert main(["process", str(bag), str(out), "--outputs", "disparity", *options]) == 0
    return out


def assert_same(a: Disparities, b: Disparities) -> None:
    assert sorted(a) == sorted(b) and len(a) == 6
    for stamp in a:
        np.testing.assert_array_equal(a[stamp], b[stamp], err_msg=f"frame {stamp}")


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("recordings")


@pytest.fixture(scope="module")
def reference(folder: Path) -> Disparities:
    """The frames as a ROS 2 bag (Image + CameraInfo), processed: what every other form must give. It is
    written here rather than taken from bags/euroc_raw, whose camera_infos the OpenCV that made it computed
    (OpenCV 4.6's stereoRectify puts P 0.01 px from 5.x's): each form is the same computation on this machine."""
    return disparities(processed(write_bag(folder / "ros2.mcap", layout()), folder / "reference"), "/stereo/disparity")


@pytest.fixture(scope="module")
def euroc_ros1(folder: Path) -> Path:
    """The official EuRoC bag layout: ROS 1, /cam0/image_raw and /cam1/image_raw, no camera_info."""
    return write_bag(folder / "euroc_official.bag", EUROC_LAYOUT, storage="rosbag1")


# ---------------------------------------------------------------- ROS 1 bags and calibration files


def test_ros1_bag_with_camera_info_gives_the_ros2_disparity_bit_for_bit(folder: Path, reference: Disparities) -> None:
    bag = write_bag(folder / "with_info.bag", layout(), storage="rosbag1")
    assert bag.is_file()
    assert_same(disparities(processed(bag, folder / "ros1_out"), "/stereo/disparity"), reference)


def test_euroc_ros1_bag_with_a_kalibr_camchain(euroc_ros1: Path, folder: Path, reference: Disparities) -> None:
    """The camchain made from the dataset's sensor files rectifies as the sensor files do: same disparity."""
    out = processed(euroc_ros1, folder / "camchain_out", "--camera-info", str(CAMCHAIN))
    assert_same(disparities(out, "/disparity"), reference)


def test_euroc_ros1_bag_rectifies_rows_to_under_half_a_pixel(euroc_ros1: Path) -> None:
    choice = TopicChoice(calibration=read_stereo_calibration(CAMCHAIN))
    results = check_bag(euroc_ros1, choice, every=1)
    judged = [check.median_dy for _, check in results if check.level != Level.STALE]
    assert len(judged) == 6
    level, message = overall(results)
    assert level == Level.OK and float(np.median(judged)) < 0.5, message


def test_euroc_ros1_bag_without_calibration_asks_for_one(
    euroc_ros1: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["process", str(euroc_ros1), str(tmp_path / "out")]) == 1
    error = capsys.readouterr().err
    assert "/cam0/image_raw + /cam1/image_raw but no camera_info" in error and "--camera-info" in error
    assert list(tmp_path.iterdir()) == []


def test_every_calibration_file_layout_gives_the_same_rectification(tmp_path: Path) -> None:
    sensor = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    euroc_folder = tmp_path / "mav0"
    for cam in ("cam0", "cam1"):
        (euroc_folder / cam).mkdir(parents=True)
        (euroc_folder / cam / "sensor.yaml").write_bytes((EUROC / f"{cam}_sensor.yaml").read_bytes())
    for source in (CAMCHAIN, EUROC, tmp_path):
        left, right = read_stereo_calibration(source)
        assert_same_calibration(left, sensor[0], source)
        assert_same_calibration(right, sensor[1], source)
    with pytest.raises(CalibrationError, match=r"no calibration found.*camchain"):
        read_stereo_calibration(EUROC / "left")
    with pytest.raises(CalibrationError, match="not a Kalibr camchain"):
        read_stereo_calibration(EUROC / "cam0_sensor.yaml")


def test_a_camchain_with_a_fisheye_camera_is_refused_with_the_reason(tmp_path: Path) -> None:
    text = CAMCHAIN.read_text().replace("camera_model: pinhole", "camera_model: omni", 1)
    (tmp_path / "camchain.yaml").write_text(text)
    with pytest.raises(CalibrationError, match=r"camera_model 'omni'.*pinhole"):
        read_stereo_calibration(tmp_path / "camchain.yaml")


@pytest.mark.parametrize("file", ["camchain", "euroc"])
def test_malformed_numbers_in_a_calibration_file_are_one_error_naming_it(tmp_path: Path, file: str) -> None:
    """Three intrinsics instead of four: an error naming the file, not a traceback from unpacking."""
    if file == "camchain":
        lines = CAMCHAIN.read_text().splitlines(keepends=True)
        first = next(i for i, line in enumerate(lines) if line.strip().startswith("intrinsics:"))
        lines[first] = lines[first].rsplit(",", 1)[0] + "]\n"
        (tmp_path / "camchain.yaml").write_text("".join(lines))
        path = tmp_path / "camchain.yaml"
    else:
        for side in ("cam0", "cam1"):
            (tmp_path / side).mkdir()
            text = (EUROC / f"{side}_sensor.yaml").read_text()
            (tmp_path / side / "sensor.yaml").write_text(text.replace("intrinsics: [", "intrinsics: [1.0, ", 1))
        path = tmp_path
    with pytest.raises(CalibrationError, match=r"malformed calibration values \(ValueError"):
        read_stereo_calibration(path)


# ---------------------------------------------------------------- compressed images


@pytest.fixture(scope="module")
def compressed_outputs(folder: Path) -> dict[str, Disparities]:
    outputs = {}
    for codec in ("png", "jpeg"):
        bag = write_bag(folder / codec, layout(compress_images=codec))
        topics = read_messages(bag, ["/stereo/left/image_raw/compressed"])
        assert topics["/stereo/left/image_raw/compressed"][0].format == f"mono8; {codec} compressed mono8"
        outputs[codec] = disparities(processed(bag, folder / f"{codec}_out"), "/stereo/disparity")
    return outputs


def test_png_compressed_bag_equals_the_raw_bag(
    compressed_outputs: dict[str, Disparities], reference: Disparities
) -> None:
    assert_same(compressed_outputs["png"], reference)


def test_jpeg_compressed_bag_agrees_within_one_pixel(
    compressed_outputs: dict[str, Disparities], reference: Disparities
) -> None:
    jpeg = compressed_outputs["jpeg"]
    assert sorted(jpeg) == sorted(reference)
    both = close = 0
    for stamp, expected in reference.items():
        valid = np.isfinite(expected) & np.isfinite(jpeg[stamp])
        both += int(valid.sum())
        close += int((np.abs(expected[valid] - jpeg[stamp][valid]) <= 1.0).sum())
        assert valid.sum() > 0.8 * np.isfinite(expected).sum()  # JPEG loses little coverage
    assert close / both >= 0.90, f"{100 * close / both:.1f} % within 1 px"


def test_a_damaged_jpeg_skips_its_frame_only(folder: Path, tmp_path: Path) -> None:
    bag = tmp_path / "damaged"
    types = rosbags_types()
    frames = list(read_frames([EUROC]))
    with BagWriter(bag) as writer:
        write_stream(frames, writer, StreamLayout(compress_images="jpeg", overrides={"left_image": "/unused"}))
        left_topic = StreamLayout(compress_images="jpeg").topics()[0]
        for index, frame in enumerate(frames):
            stamp = int(frame.stamp_ns or 0)
            message = array_to_compressed(types, make_header(types, stamp, "cam0"), frame.left, "jpeg")
            if index == 2:
                message.data = message.data[: message.data.size // 2]  # cut off in transport
            writer.write(left_topic, message, stamp)
    summary = process_bag(bag, tmp_path / "out", make_params(), ProcessOptions(outputs=("disparity",)))
    assert summary.frames_out == 5
    [(reason, count)] = summary.skipped.items()
    assert count == 1 and "damaged JPEG" in reason


def test_image_transport_format_strings() -> None:
    assert compressed_format("bgr8; jpeg compressed bgr8") == ("jpeg", "bgr8")
    assert compressed_format("rgb8; png compressed rgb8") == ("png", "rgb8")
    assert compressed_format("jpeg") == ("jpeg", "")
    assert compressed_format("PNG") == ("png", "")
    with pytest.raises(ImageError, match="'16UC1; compressedDepth' is not supported"):
        compressed_format("16UC1; compressedDepth")


def test_colour_pngs_decode_to_the_pipeline_s_bgr_whatever_the_channel_order_label() -> None:
    types = rosbags_types()
    bgr = np.random.default_rng(1).integers(0, 255, (8, 10, 3), dtype=np.uint8)
    message = array_to_compressed(types, make_header(types, 1, "cam"), bgr, "png")
    assert message.format == "bgr8; png compressed bgr8"
    np.testing.assert_array_equal(compressed_to_pipeline(message), bgr)
    message.format = "rgb8; png compressed rgb8"  # an encoder that was handed RGB: its file holds RGB
    np.testing.assert_array_equal(compressed_to_pipeline(message), bgr[:, :, ::-1])


# ---------------------------------------------------------------- topic names


IMAGE, COMPRESSED, INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"


def camera(image_topic: str, msgtype: str = IMAGE) -> dict[str, str]:
    return {image_topic: msgtype, image_topic.removesuffix("/compressed").rsplit("/", 1)[0] + "/camera_info": INFO}


@pytest.mark.parametrize(
    ("left", "right", "namespace", "rectified"),
    [
        ("/cam0/image_raw", "/cam1/image_raw", "", False),  # EuRoC, TUM-VI
        ("/camera/infra1/image_rect_raw", "/camera/infra2/image_rect_raw", "/camera", False),  # RealSense
        ("/zed_node/left/image_rect_color", "/zed_node/right/image_rect_color", "/zed_node", True),  # ZED
        ("/kitti/camera_gray_left/image_raw", "/kitti/camera_gray_right/image_raw", "/kitti", False),  # kitti2bag
        ("/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed", "/stereo", False),
    ],
)
def test_stereo_pairs_are_found_by_the_names_cameras_use(
    left: str, right: str, namespace: str, rectified: bool
) -> None:
    msgtype = COMPRESSED if left.endswith("/compressed") else IMAGE
    topics = {**camera(left, msgtype), **camera(right, msgtype), "/imu0": "sensor_msgs/msg/Imu"}
    found = find_stereo_topics(topics)
    assert found.images == (left, right)
    assert (found.namespace, found.rectified) == (namespace, rectified)


def test_raw_images_win_over_their_compressed_copies_and_several_sets_are_listed() -> None:
    topics = {
        **camera("/front/left/image_raw"),
        **camera("/front/right/image_raw"),
        **camera("/front/left/image_raw/compressed", COMPRESSED),
        **camera("/front/right/image_raw/compressed", COMPRESSED),
    }
    assert find_stereo_topics(topics).images == ("/front/left/image_raw", "/front/right/image_raw")
    topics.update({**camera("/rear/cam0/image_raw"), **camera("/rear/cam1/image_raw")})
    with pytest.raises(BagError, match=r"several namespaces \(/front, /rear\).*/rear/cam0/image_raw \+"):
        find_stereo_topics(topics)


def test_left_and_right_name_the_topics_when_the_conventions_do_not_fit(tmp_path: Path, reference: Disparities) -> None:
    names = {"left_image": "/a/image_raw", "left_info": "/a/camera_info"}
    names |= {"right_image": "/b/image_raw", "right_info": "/b/camera_info"}
    bag = write_bag(tmp_path / "odd", layout(namespace="/", overrides=names))
    with pytest.raises(BagError, match=r"no complete stereo topic set.*--left and --right"):
        process_bag(bag, tmp_path / "out", make_params())
    out = processed(bag, tmp_path / "out", "--left", "/a/image_raw", "--right", "/b/image_raw")
    assert_same(disparities(out, "/disparity"), reference)


def test_make_bag_names_a_ros1_bag_as_a_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["make-bag", str(EUROC), str(tmp_path / "out"), "--storage", "rosbag1"]) == 1
    assert "name it *.bag" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
