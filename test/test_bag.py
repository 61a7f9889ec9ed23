"""Offline bag tools on the bundled real recordings: process, make-bag, accuracy, no half-written output."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from waiting import wait_until

from stereo_depth.atomic_output import OutputError
from stereo_depth.bag.export import read_ply
from stereo_depth.bag.ground_truth import read_ground_truth_index
from stereo_depth.bag.make import StreamLayout, write_stream
from stereo_depth.bag.process import ProcessOptions, ProcessSummary, process_bag
from stereo_depth.bag.reader import find_stereo_topics, read_messages
from stereo_depth.bag.sources import read_frames
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.metrics import accuracy
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import BagError, ParameterError
from stereo_depth.formats.scenes import load_scene
from stereo_depth.messages import camera_info_from_msg, cloud_to_arrays, disparity_from_msg, image_to_array, stamp_to_ns
from stereo_depth.options import NodeOptions

from conftest import DATA, EUROC, SCENES, read_image

BAGS = Path(__file__).resolve().parents[1] / "bags"
EUROC_BAG = BAGS / "euroc_raw"
MIDDLEBURY_BAG = BAGS / "middlebury"
NS = "/stereo"


def disparities(bag: Path, namespace: str = NS) -> dict[int, np.ndarray]:
    """{stamp: DisparityImage pixels (offset-adjusted, NaN invalid)} of a processed bag."""
    messages = read_messages(bag, [f"{namespace}/disparity"])[f"{namespace}/disparity"]
    return {stamp_to_ns(m.header.stamp): disparity_from_msg(m) for m in messages}


def assert_same_disparity(a: dict[int, np.ndarray], b: dict[int, np.ndarray]) -> None:
    assert sorted(a) == sorted(b)
    for stamp in a:
        np.testing.assert_array_equal(a[stamp], b[stamp], err_msg=f"frame {stamp}")


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture(scope="module")
def euroc_processed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ProcessSummary]:
    out = tmp_path_factory.mktemp("euroc") / "out"
    return out, process_bag(EUROC_BAG, out, make_params())


@pytest.fixture(scope="module")
def middlebury_processed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("middlebury") / "out"
    process_bag(MIDDLEBURY_BAG, out, make_params())
    return out


# ---------------------------------------------------------------- bundled bags


@pytest.mark.parametrize("bag", [EUROC_BAG, MIDDLEBURY_BAG], ids=lambda p: p.name)
def test_bundled_bag_has_a_stereo_camera_stream(bag: Path) -> None:
    topics = [f"{NS}/left/image_raw", f"{NS}/left/camera_info", f"{NS}/right/image_raw", f"{NS}/right/camera_info"]
    messages = read_messages(bag, topics)
    counts = {len(v) for v in messages.values()}
    assert len(counts) == 1 and counts.pop() >= 3
    for left, info in zip(messages[topics[0]], messages[topics[1]], strict=True):
        assert stamp_to_ns(left.header.stamp) == stamp_to_ns(info.header.stamp)
        assert (left.width, left.height) == (info.width, info.height)


def test_euroc_bag_is_raw_distorted_mono_with_rectifying_camera_infos() -> None:
    messages = read_messages(EUROC_BAG, [f"{NS}/left/image_raw", f"{NS}/left/camera_info", f"{NS}/right/camera_info"])
    image = messages[f"{NS}/left/image_raw"][0]
    assert image.encoding == "mono8" and (image.width, image.height) == (752, 480)
    names = sorted(p.stem for p in (EUROC / "left").glob("*.png"))
    assert [str(stamp_to_ns(m.header.stamp)) for m in messages[f"{NS}/left/image_raw"]] == names
    camera = StereoCamera(
        camera_info_from_msg(messages[f"{NS}/left/camera_info"][0]),
        camera_info_from_msg(messages[f"{NS}/right/camera_info"][0]),
    )
    assert camera.needs_rectification("left") and camera.needs_rectification("right")
    assert camera.baseline == pytest.approx(0.110, abs=0.002)


def test_middlebury_bag_is_rectified_with_different_principal_points() -> None:
    messages = read_messages(MIDDLEBURY_BAG, [f"{NS}/left/camera_info", f"{NS}/right/camera_info"])
    for left, right in zip(messages[f"{NS}/left/camera_info"], messages[f"{NS}/right/camera_info"], strict=True):
        camera = StereoCamera(camera_info_from_msg(left), camera_info_from_msg(right))
        assert not camera.needs_rectification("left") and not camera.needs_rectification("right")
        assert camera.cx_right - camera.cx_left > 20  # doffs of the 2014 scenes


# ---------------------------------------------------------------- process


def test_process_writes_every_output_for_every_pair_with_the_input_stamps(
    euroc_processed: tuple[Path, ProcessSummary],
) -> None:
    out, summary = euroc_processed
    assert (summary.left_images, summary.frames_out, summary.unmatched, sum(summary.skipped.values())) == (6, 6, 0, 0)
    outputs = ["disparity", "depth", "points2", "left/image_rect"]
    messages = read_messages(out, [f"{NS}/{name}" for name in outputs])
    inputs = read_messages(EUROC_BAG, [f"{NS}/left/image_raw"])[f"{NS}/left/image_raw"]
    expected = [(stamp_to_ns(m.header.stamp), m.header.frame_id) for m in inputs]
    for name in outputs:
        assert [(stamp_to_ns(m.header.stamp), m.header.frame_id) for m in messages[f"{NS}/{name}"]] == expected


def test_process_disparity_equals_the_pipeline_on_the_same_messages(
    euroc_processed: tuple[Path, ProcessSummary],
) -> None:
    out, _ = euroc_processed
    names = [f"{NS}/left/image_raw", f"{NS}/left/camera_info", f"{NS}/right/image_raw", f"{NS}/right/camera_info"]
    inputs = read_messages(EUROC_BAG, names)
    pipeline = StereoPipeline(make_params())
    produced = disparities(out)
    for left, left_info, right, right_info in zip(*(inputs[n] for n in names), strict=True):
        camera = pipeline.camera_for(camera_info_from_msg(left_info), camera_info_from_msg(right_info))
        result = pipeline.process(image_to_array(left), image_to_array(right), camera)
        expected = np.subtract(result.disparity, np.float32(camera.disparity_offset), dtype=np.float32)
        np.testing.assert_array_equal(produced[stamp_to_ns(left.header.stamp)], expected)


def test_mcap_and_sqlite3_input_give_the_same_result(tmp_path: Path) -> None:
    """The same messages stored both ways (written here, so their camera_infos come from this machine's
    OpenCV, as the bundled bag's came from the one that made it) give the same disparity bit for bit."""
    outputs = {}
    for storage, suffix in (("mcap", "*.mcap"), ("sqlite3", "*.db3")):
        bag = tmp_path / f"euroc_{storage}"
        with BagWriter(bag, storage=storage) as writer:
            write_stream(read_frames([EUROC]), writer, StreamLayout(left_frame_id="cam0", right_frame_id="cam1"))
        assert next(bag.glob(suffix))
        out = tmp_path / f"out_{storage}"
        assert main(["process", str(bag), str(out), "--storage", storage, "--outputs", "disparity"]) == 0
        assert next(out.glob(suffix))
        outputs[storage] = disparities(out)
    assert len(outputs["mcap"]) == 6
    assert_same_disparity(outputs["sqlite3"], outputs["mcap"])


def test_chosen_outputs_only_and_compressed_chunks_change_nothing_else(
    tmp_path: Path, euroc_processed: tuple[Path, ProcessSummary]
) -> None:
    out = tmp_path / "disparity_only"
    assert main(["process", str(EUROC_BAG), str(out), "--outputs", "disparity", "--compress"]) == 0
    metadata = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert [t["topic_metadata"]["name"] for t in metadata["topics_with_message_count"]] == [f"{NS}/disparity"]
    assert b"zstd" in next(out.glob("*.mcap")).read_bytes()  # MCAP chunk compression
    assert b"zstd" not in next(euroc_processed[0].glob("*.mcap")).read_bytes()  # the default writes them plain
    assert_same_disparity(disparities(out), disparities(euroc_processed[0]))


def test_middlebury_accuracy_against_ground_truth(middlebury_processed: Path) -> None:
    """Measured with the default profile: bad-2 of estimated 5.7 / 4.8 / 13.2 %, density 84-86 %."""
    truth = read_ground_truth_index(BAGS / "middlebury_gt")
    infos = read_messages(MIDDLEBURY_BAG, [f"{NS}/left/camera_info", f"{NS}/right/camera_info"])
    offsets = {
        stamp_to_ns(left.header.stamp): StereoCamera(
            camera_info_from_msg(left), camera_info_from_msg(right)
        ).disparity_offset
        for left, right in zip(infos[f"{NS}/left/camera_info"], infos[f"{NS}/right/camera_info"], strict=True)
    }
    produced = disparities(middlebury_processed)
    assert sorted(produced) == sorted(truth) and len(truth) == 3
    scores = {}
    for stamp, gt in truth.items():
        matched = produced[stamp] + np.float32(offsets[stamp])  # back to x_left - x_right, as the GT
        scores[gt.scene] = accuracy(matched, gt.disparity, gt.mask)
    assert all(s.density > 0.80 for s in scores.values()), scores
    assert all(s.bad2_est < 0.18 for s in scores.values()), scores
    assert np.mean([s.bad2_est for s in scores.values()]) < 0.10, scores


# doffs (px) from each scene's calib.txt, Middlebury 2014: Z = f * B / (d + doffs)
DOFFS = {"middlebury2014_q/adirondack": 53.271, "middlebury2014_q/motorcycle": 32.778, "middlebury2014_q/piano": 31.34}


def test_middlebury_depth_uses_the_principal_point_offset(middlebury_processed: Path) -> None:
    """Depth must follow Z = f*B / (d + doffs); forgetting cx_l != cx_r would be 30-80 % off here."""
    truth = read_ground_truth_index(BAGS / "middlebury_gt")
    infos = read_messages(MIDDLEBURY_BAG, [f"{NS}/left/camera_info", f"{NS}/right/camera_info"])
    depth = read_messages(middlebury_processed, [f"{NS}/depth"])[f"{NS}/depth"]
    pairs = zip(infos[f"{NS}/left/camera_info"], infos[f"{NS}/right/camera_info"], depth, strict=True)
    for left, right, message in pairs:
        camera = StereoCamera(camera_info_from_msg(left), camera_info_from_msg(right))
        gt = truth[stamp_to_ns(message.header.stamp)]
        doffs = DOFFS[gt.scene]
        assert camera.cx_right - camera.cx_left == pytest.approx(doffs, abs=1e-3)
        z = image_to_array(message)
        assert gt.mask is not None
        valid = np.isfinite(z) & np.isfinite(gt.disparity) & gt.mask
        assert valid.mean() > 0.5
        relative = z[valid] * (gt.disparity[valid] + doffs) / (camera.fx * camera.baseline) - 1.0
        assert np.median(np.abs(relative)) < 0.02


# ---------------------------------------------------------------- make-bag round trip


def test_make_bag_then_process_gives_the_disparity_of_eval(tmp_path: Path) -> None:
    scene_dir = SCENES / "artl"
    bag, out = tmp_path / "artl", tmp_path / "artl_out"
    assert main(["make-bag", str(scene_dir), str(bag), "--rate", "5", "--namespace", "/cam"]) == 0
    scene = load_scene(scene_dir)
    disparity_range = scene.disparity_range()
    assert main(["process", str(bag), str(out), "--set", f"disparity_range={disparity_range}"]) == 0
    # eval's path: rectified scene images, no camera (see commands/eval.py)
    params = make_params("default", {"disparity_range": disparity_range})
    expected = StereoPipeline(params).process(scene.left, scene.right, None, rectified=True, want_points=False)
    offset = np.float32(float(scene.calib["doffs"]) * -1.0)  # cx_l - cx_r
    (produced,) = disparities(out, "/cam").values()
    np.testing.assert_array_equal(produced, np.subtract(expected.disparity, offset, dtype=np.float32))


def test_make_bag_restamps_renames_and_crops(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    args = [
        "make-bag",
        str(EUROC),
        str(bag),
        "--rate",
        "20",
        "--start",
        "100",
        "--namespace",
        "robot/stereo",
        "--topic",
        "right_image=/other/right",
        "--crop",
        "640x400",
    ]
    assert main(args) == 0
    messages = read_messages(bag, ["/robot/stereo/left/image_raw", "/other/right", "/robot/stereo/left/camera_info"])
    stamps = [stamp_to_ns(m.header.stamp) for m in messages["/other/right"]]
    assert stamps == [100_000_000_000 + i * 50_000_000 for i in range(6)]
    assert {(m.width, m.height) for m in messages["/robot/stereo/left/image_raw"]} == {(640, 400)}
    info = messages["/robot/stereo/left/camera_info"][0]
    assert (info.width, info.height) == (640, 400)
    assert info.k[2] == pytest.approx(367.215 - 56, abs=1e-3)  # cx of cam0_sensor.yaml, shifted by the crop


def test_make_bag_reads_ros_camera_info_yaml(tmp_path: Path) -> None:
    """fx, the baseline and each camera's own cx from left.yaml / right.yaml reach the bag's camera_info
    and, through `process`, the DisparityImage."""
    folder = tmp_path / "capture"
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    scene = load_scene(SCENES / "cones")
    for i in range(2):
        cv2.imwrite(str(folder / "left" / f"{i:03d}.png"), scene.left)
        cv2.imwrite(str(folder / "right" / f"{i:03d}.png"), scene.right)
    h, w = scene.left.shape[:2]
    fx, fy, baseline = 512.5, 510.0, 0.16
    cx = {"left": w / 2 + 3.5, "right": w / 2 - 2.25}
    for side, tx in (("left", 0.0), ("right", -baseline * fx)):
        calib = {
            "image_width": w,
            "image_height": h,
            "distortion_model": "plumb_bob",
            "camera_matrix": {"rows": 3, "cols": 3, "data": [fx, 0, cx[side], 0, fy, h / 2, 0, 0, 1]},
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0, 0, 0, 0, 0]},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
            "projection_matrix": {"rows": 3, "cols": 4, "data": [fx, 0, cx[side], tx, 0, fy, h / 2, 0, 0, 0, 1, 0]},
        }
        (folder / f"{side}.yaml").write_text(yaml.safe_dump(calib))
    bag, out = tmp_path / "bag", tmp_path / "out"
    assert main(["make-bag", str(folder), str(bag)]) == 0
    infos = read_messages(bag, [f"{NS}/left/camera_info", f"{NS}/right/camera_info"])
    for side in ("left", "right"):
        messages = infos[f"{NS}/{side}/camera_info"]
        assert len(messages) == 2
        for info in messages:
            assert (info.width, info.height, info.distortion_model) == (w, h, "plumb_bob")
            assert (info.k[0], info.k[2], info.k[4]) == (fx, cx[side], fy)
            assert (info.p[0], info.p[2], info.p[5]) == (fx, cx[side], fy)
    right = infos[f"{NS}/right/camera_info"][0]
    assert -right.p[3] / right.p[0] == pytest.approx(baseline)
    summary = process_bag(bag, out, make_params())
    assert summary.frames_out == 2
    for disparity in read_messages(out, [f"{NS}/disparity"])[f"{NS}/disparity"]:
        assert (disparity.f, disparity.t) == (fx, pytest.approx(baseline))
        assert disparity.min_disparity == -(cx["left"] - cx["right"])  # 0 minus the principal-point offset


def test_make_bag_reads_a_euroc_mav0_folder(tmp_path: Path) -> None:
    """EuRoC's own layout: mav0/cam0/data/<ns stamp>.png with mav0/cam0/sensor.yaml (and cam1)."""
    mav0 = tmp_path / "V1_01_easy" / "mav0"
    names = sorted(p.name for p in (EUROC / "left").glob("*.png"))[:3]
    for cam, side in (("cam0", "left"), ("cam1", "right")):
        (mav0 / cam / "data").mkdir(parents=True)
        shutil.copy(EUROC / f"{cam}_sensor.yaml", mav0 / cam / "sensor.yaml")
        for name in names:
            shutil.copy(EUROC / side / name, mav0 / cam / "data" / name)
    bag = tmp_path / "bag"
    assert main(["make-bag", str(tmp_path / "V1_01_easy"), str(bag)]) == 0
    topics = [f"{NS}/left/image_raw", f"{NS}/left/camera_info", f"{NS}/right/image_raw", f"{NS}/right/camera_info"]
    messages = read_messages(bag, topics)
    stamps = [int(Path(name).stem) for name in names]  # the file names' nanosecond stamps
    for topic in topics:
        assert [stamp_to_ns(m.header.stamp) for m in messages[topic]] == stamps, topic
    for side, topic in (("left", topics[0]), ("right", topics[2])):
        for name, image in zip(names, messages[topic], strict=True):
            np.testing.assert_array_equal(image_to_array(image), read_image(EUROC / side / name, cv2.IMREAD_GRAYSCALE))
    left_info, right_info = messages[topics[1]][0], messages[topics[3]][0]
    assert (left_info.width, left_info.height, left_info.distortion_model) == (752, 480, "plumb_bob")
    assert list(left_info.k[[0, 2, 4, 5]]) == [458.654, 367.215, 457.296, 248.375]  # cam0 intrinsics
    np.testing.assert_allclose(left_info.d[:4], [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    assert -right_info.p[3] / right_info.p[0] == pytest.approx(0.1101, abs=0.0005)  # EuRoC: 110.1 mm


# ---------------------------------------------------------------- failures leave nothing behind


def test_interrupted_process_leaves_no_bag(tmp_path: Path) -> None:
    out = tmp_path / "out"

    def interrupt(index: int, *_: Any) -> None:
        if index == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        process_bag(EUROC_BAG, out, make_params(), on_frame=interrupt)
    assert leftovers(tmp_path) == []


def test_ctrl_c_on_the_command_leaves_no_bag(tmp_path: Path) -> None:
    out = tmp_path / "out"
    command = [
        sys.executable,
        "-m",
        "stereo_depth.cli",
        "process",
        str(EUROC_BAG),
        str(out),
        "--ply",
        str(tmp_path / "ply"),
    ]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # pytest may run us with SIGINT ignored
    )
    # the first PLY means the output bag is being written
    wait_until(lambda: process.poll() is not None or any((tmp_path / "ply").glob("*.ply")), "the first PLY", 60.0)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err.decode()
    assert "interrupted" in err.decode()
    assert leftovers(tmp_path) == ["ply"]  # no bag, no hidden temporary folder


def test_existing_output_is_refused_unless_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(OutputError, match="--overwrite"):
        process_bag(MIDDLEBURY_BAG, out, make_params())
    assert (out / "keep.txt").read_text() == "mine"
    process_bag(MIDDLEBURY_BAG, out, make_params(), ProcessOptions(overwrite=True))
    assert not (out / "keep.txt").exists() and len(disparities(out)) == 3
    assert leftovers(tmp_path) == ["out"]


def test_process_builds_outputs_with_the_nodes_output_options(tmp_path: Path) -> None:
    """The node's use_color, avoid_point_cloud_padding, confidence and colour image exist offline too."""
    out = tmp_path / "out"
    outputs = ["points2", "confidence", "left/image_rect_color", "disparity"]
    options = ["--set", "use_color=false", "--set", "avoid_point_cloud_padding=true", "--profile", "quality"]
    assert main(["process", str(MIDDLEBURY_BAG), str(out), "--outputs", *outputs, *options]) == 0
    messages = read_messages(out, [f"{NS}/{name}" for name in outputs])
    assert all(len(messages[f"{NS}/{name}"]) == 3 for name in outputs)
    cloud = messages[f"{NS}/points2"][0]
    assert [f.name for f in cloud.fields] == ["x", "y", "z"] and cloud.point_step == 12
    colour, confidence = messages[f"{NS}/left/image_rect_color"][0], messages[f"{NS}/confidence"][0]
    assert colour.encoding == "bgr8" and confidence.encoding == "32FC1"
    conf = image_to_array(confidence)
    disparity = disparity_from_msg(messages[f"{NS}/disparity"][0])
    assert conf.shape == disparity.shape and np.all(conf[~np.isfinite(disparity)] == 0.0)
    xyz, rgb = cloud_to_arrays(cloud)
    assert rgb is None and np.isfinite(xyz[:, :, 2]).mean() > 0.5


def test_process_honours_max_image_pixels_and_names_the_topic(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["process", str(EUROC_BAG), str(out), "--set", "max_image_pixels=1000"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ERROR: no frame was processed from 6 left / 6 right images: 6 ")
    assert f"skipped because {NS}/left/image_raw: image is 752x480, more than the limit of 1000 pixels" in err
    assert not out.exists() and leftovers(tmp_path) == []  # no empty bag


def test_a_mask_that_cannot_be_used_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["process", str(EUROC_BAG), str(out), "--set", f"mask_image={tmp_path / 'none.png'}"]) == 1
    assert f"ERROR: mask_image {tmp_path / 'none.png'}: cannot read it" in capsys.readouterr().err
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.full((48, 75), 255, np.uint8))
    assert main(["process", str(EUROC_BAG), str(out), "--set", f"mask_image={small}"]) == 1
    assert f"6 skipped because mask_image {small} is 75x48 but the left camera is 752x480" in capsys.readouterr().err


def test_misspelt_parameters_name_the_closest_known_one(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "params.yaml"
    node_only = "publish_depth: false, matching_threads: 2"  # a stereo_node file: no warning for these
    params.write_text(f"stereo_node:\n  ros__parameters: {{dispartiy_range: 128, use_colour: false, {node_only}}}\n")
    out = tmp_path / "out"
    assert main(["process", str(MIDDLEBURY_BAG), str(out), "--params", str(params), "--outputs", "disparity"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("WARNING")]
    assert warnings == [
        f"WARNING: --params {params}: unknown parameters, ignored: 'dispartiy_range' (did you mean "
        "'disparity_range'?); 'use_colour' (did you mean 'use_color'?)"
    ]
    assert main(["process", str(MIDDLEBURY_BAG), str(out), "--set", "dispartiy_range=128", "--overwrite"]) == 1
    assert "ERROR: --set: unknown parameters, ignored: 'dispartiy_range' (did you mean 'disparity_range'?)" in (
        capsys.readouterr().err
    )


def test_bag_without_stereo_topics_names_the_topics_it_has(tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert main(["process", str(MIDDLEBURY_BAG), str(tmp_path / "first")]) == 0
    with pytest.raises(BagError, match=r"no complete stereo topic set.*/stereo/disparity"):
        process_bag(tmp_path / "first", out, make_params())
    assert not out.exists()


def test_several_stereo_sets_need_a_namespace(tmp_path: Path) -> None:
    bag = tmp_path / "two"
    with BagWriter(bag) as writer:
        for namespace in ("/front", "/rear"):
            write_stream(read_frames([SCENES / "artl"]), writer, StreamLayout(namespace=namespace))
    with pytest.raises(BagError, match=r"several namespaces \(/front, /rear\).*--namespace"):
        process_bag(bag, tmp_path / "out", make_params())
    summary = process_bag(bag, tmp_path / "out", make_params(), ProcessOptions(namespace="rear"))
    assert summary.frames_out == 1
    assert len(disparities(tmp_path / "out", "/rear")) == 1


def test_unreadable_inputs_say_what_to_pass(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="does not exist"):
        process_bag(tmp_path / "missing", tmp_path / "out", make_params())
    with pytest.raises(BagError, match="pass its bag folder"):
        process_bag(next(EUROC_BAG.glob("*.mcap")), tmp_path / "out", make_params())
    assert main(["process", str(DATA), str(tmp_path / "out")]) == 1
    assert leftovers(tmp_path) == []


# ---------------------------------------------------------------- sync, parameters, pictures


def test_unpaired_stamps_are_reported_and_approximate_sync_pairs_them(tmp_path: Path) -> None:
    """Right camera stamped 3 ms after the left one, as with an unsynchronised pair of drivers."""
    bag = tmp_path / "skewed"
    with BagWriter(bag) as writer:
        frames = list(read_frames([SCENES / "artl"])) * 3
        layout = StreamLayout(rate_hz=10.0)
        left_layout = StreamLayout(rate_hz=10.0, overrides={"right_image": "/unused/r", "right_info": "/unused/ri"})
        right_layout = StreamLayout(
            rate_hz=10.0,
            start_ns=layout.start_ns + 3_000_000,
            overrides={"left_image": "/unused/l", "left_info": "/unused/li"},
        )
        write_stream(frames, writer, left_layout)
        write_stream(frames, writer, right_layout)
    with pytest.raises(BagError, match=r"from 3 left / 3 right images: no set .* \(12 unmatched\).*--approximate-sync"):
        process_bag(bag, tmp_path / "exact", make_params())
    assert not (tmp_path / "exact").exists()
    options = ProcessOptions(sync=NodeOptions(approximate_sync=True, approximate_sync_tolerance_seconds=0.005))
    assert process_bag(bag, tmp_path / "approx", make_params(), options).frames_out == 3


def test_params_file_applies_and_set_wins(tmp_path: Path) -> None:
    from stereo_depth.commands.process import read_params_file

    params_file = tmp_path / "params.yaml"
    params_file.write_text(
        "/**:\n  ros__parameters:\n    disparity_range: 32\n    queue_size: 7\n"
        "stereo_node:\n  ros__parameters:\n    stereo_algorithm: 0\n    correlation_window_size: 15\n"
    )
    assert read_params_file(params_file)["queue_size"] == 7
    out = tmp_path / "out"
    command = ["process", str(MIDDLEBURY_BAG), str(out), "--params", str(params_file), "--set", "disparity_range=48"]
    assert main(command) == 0
    first = read_messages(out, [f"{NS}/disparity"])[f"{NS}/disparity"][0]
    assert first.max_disparity - first.min_disparity == pytest.approx(47)  # --set won over the file's 32
    expected = make_params("default", {"matcher": "bm", "correlation_window_size": 15, "disparity_range": 48})
    process_bag(MIDDLEBURY_BAG, tmp_path / "expected", expected)
    assert_same_disparity(disparities(out), disparities(tmp_path / "expected"))
    params_file.write_text("disparity_range: 32\n")
    with pytest.raises(ParameterError, match="ros__parameters"):
        read_params_file(params_file)


def test_png_and_ply_per_frame(tmp_path: Path) -> None:
    png, ply = tmp_path / "png", tmp_path / "ply"
    out = tmp_path / "out"
    summary = process_bag(MIDDLEBURY_BAG, out, make_params(), ProcessOptions(png_dir=png, ply_dir=ply))
    assert len(list(png.glob("*.png"))) == len(list(ply.glob("*.ply"))) == summary.frames_out == 3
    clouds = read_messages(out, [f"{NS}/points2"])[f"{NS}/points2"]
    xyz, rgb = cloud_to_arrays(clouds[0])
    vertices = read_ply(sorted(ply.glob("*.ply"))[0])
    valid = np.isfinite(xyz).all(axis=2)
    assert vertices.size == valid.sum()
    np.testing.assert_array_equal(vertices["z"], xyz[valid][:, 2])
    assert rgb is not None
    np.testing.assert_array_equal(vertices["red"], ((rgb[valid] >> 16) & 255).astype(np.uint8))


def test_stereo_topics_are_found_by_suffix() -> None:
    image, info = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"
    topics = {
        "/a/left/image_rect": image,
        "/a/left/camera_info": info,
        "/a/right/image_rect": image,
        "/a/right/camera_info": info,
        "/a/left/image_raw": image,
        "/a/right/image_raw": image,
    }
    found = find_stereo_topics(topics)
    assert found.namespace == "/a" and not found.rectified
    del topics["/a/right/image_raw"]
    assert find_stereo_topics(topics).rectified
    root = {"/left/image_raw": image, "/left/camera_info": info, "/right/image_raw": image, "/right/camera_info": info}
    assert find_stereo_topics(root).output("disparity") == "/disparity"


def test_bag_tools_work_without_rclpy() -> None:
    """The offline tools are for laptops with no ROS install: nothing but replay may import rclpy."""
    code = (
        "import sys; import stereo_depth.cli, stereo_depth.bag.process, stereo_depth.bag.make; "
        "stereo_depth.cli.build_parser(); print('rclpy' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert result.stdout.strip() == "False"
