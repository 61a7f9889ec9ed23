"""`stereo-depth process` on bad bags and bad output paths: exit 1, one `ERROR:` line saying what is
wrong and what to do, and nothing left at the output path (no bag, no hidden temporary folder).

Ctrl-C in the middle is pinned in test_bag.py (test_ctrl_c_on_the_command_leaves_no_bag); the bag
without the requested topics at the API level too (test_bag_without_stereo_topics_names_the_topics_it_has).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from stereo_depth.bag.make import StreamLayout, write_stream
from stereo_depth.bag.sources import read_frames
from stereo_depth.bag.types import rosbags_types
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.messages import array_to_image, make_header

from conftest import SCENES

BAGS = Path(__file__).resolve().parents[1] / "bags"
EUROC_BAG = BAGS / "euroc_raw"  # MCAP, zstd-compressed chunks
MIDDLEBURY_BAG = BAGS / "middlebury"


def process(capsys: pytest.CaptureFixture[str], in_bag: Path, out: Path, *extra: str) -> tuple[int, str]:
    """Exit code and the one ERROR line of `stereo-depth process` (asserting there is exactly one)."""
    code = main(["process", str(in_bag), str(out), *extra])
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == (1 if code else 0), errors
    return code, errors[0] if errors else ""


def nothing_written(out: Path) -> bool:
    """No output bag and no temporary folder beside it."""
    return not out.exists() and not list(out.parent.glob(f".{out.name}*"))


def damaged_copy(tmp_path: Path, bag: Path, damage: Callable[[bytearray], bytearray]) -> Path:
    copy = tmp_path / f"damaged_{bag.name}"
    shutil.copytree(bag, copy)
    storage = next(p for p in copy.iterdir() if p.suffix in (".mcap", ".db3"))
    storage.write_bytes(bytes(damage(bytearray(storage.read_bytes()))))
    return copy


def cut_in_half(data: bytearray) -> bytearray:
    return data[: len(data) // 2]


def zero_a_block(data: bytearray) -> bytearray:
    """4 KB of zeros 40 % into the file: inside a compressed chunk (MCAP) or a page of images (sqlite3)."""
    start = int(len(data) * 0.4)
    data[start : start + 4096] = bytes(4096)
    return data


@pytest.fixture(scope="module")
def sqlite_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bag = tmp_path_factory.mktemp("sqlite") / "artl_sqlite"
    with BagWriter(bag, storage="sqlite3") as writer:
        write_stream(read_frames([SCENES / "artl"] * 3), writer, StreamLayout())
    return bag


@pytest.mark.parametrize(
    ("damage", "reason"),
    [(cut_in_half, "not a readable rosbag2"), (zero_a_block, "cannot read messages")],
    ids=["truncated", "corrupt"],
)
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_truncated_or_corrupt_bag(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    sqlite_bag: Path,
    storage: str,
    damage: Callable[[bytearray], bytearray],
    reason: str,
) -> None:
    bag = damaged_copy(tmp_path, EUROC_BAG if storage == "mcap" else sqlite_bag, damage)
    out = tmp_path / "out"
    code, error = process(capsys, bag, out)
    assert code == 1
    assert str(bag) in error and reason in error and "ros2 bag reindex" in error, error
    assert nothing_written(out)


def test_empty_bag(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    bag = tmp_path / "empty"
    with BagWriter(bag):
        pass
    code, error = process(capsys, bag, tmp_path / "out")
    assert code == 1 and "holds no messages (no topics)" in error
    assert nothing_written(tmp_path / "out")


def test_bag_without_the_requested_topics_lists_the_topics_it_has(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, error = process(capsys, MIDDLEBURY_BAG, tmp_path / "out", "--namespace", "/front")
    assert code == 1 and "under namespace '/front'" in error
    assert "/stereo/left/image_raw" in error and "/stereo/right/camera_info" in error
    assert nothing_written(tmp_path / "out")


def test_topics_of_the_wrong_message_type(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """A camera_info topic that carries images (a remap gone wrong while recording)."""
    bag = tmp_path / "wrong_type"
    with BagWriter(bag) as writer:
        write_stream(read_frames([SCENES / "artl"]), writer, StreamLayout(overrides={"left_info": "/unused"}))
        header = make_header(rosbags_types(), 1, "cam")
        writer.write("/stereo/left/camera_info", array_to_image(rosbags_types(), header, np.zeros((2, 2), np.uint8)), 1)
    code, error = process(capsys, bag, tmp_path / "out")
    assert code == 1
    assert "/stereo/left/camera_info is sensor_msgs/msg/Image, not sensor_msgs/msg/CameraInfo" in error
    assert "--camera-info" in error
    assert nothing_written(tmp_path / "out")


def test_existing_output_is_refused_unless_overwrite(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, error = process(capsys, MIDDLEBURY_BAG, out)
    assert code == 1 and "exists already" in error and "--overwrite" in error
    assert (out / "keep.txt").read_text() == "mine"
    assert process(capsys, MIDDLEBURY_BAG, out, "--overwrite")[0] == 0
    assert not (out / "keep.txt").exists()


def a_file(path: Path) -> Path:
    path.write_text("")
    return path


@pytest.mark.parametrize(
    ("make_parent", "reason"),
    [
        (lambda tmp: tmp / "missing", "is not a folder; create it first"),
        (lambda tmp: a_file(tmp / "a_file"), "is not a folder"),
        (lambda tmp: Path("/proc"), "cannot write in /proc"),  # a folder nobody, root included, writes in
    ],
    ids=["missing folder", "a file as folder", "read-only folder"],
)
def test_unwritable_output_folder(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, make_parent: Callable[[Path], Path], reason: str
) -> None:
    out = make_parent(tmp_path) / "stereo_depth_out"
    code, error = process(capsys, MIDDLEBURY_BAG, out)
    assert code == 1 and reason in error and "folder" in error
    assert not out.exists()


def test_malformed_calib_txt_is_one_error_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    scene = tmp_path / "scene"
    shutil.copytree(SCENES / "tsukuba", scene)
    calib = (scene / "calib.txt").read_text() if (scene / "calib.txt").exists() else ""
    (scene / "calib.txt").write_text(calib + "cam0=[1 2; 3]\ncam1=[1 0 0; 0 1 0; 0 0 1]\nbaseline=100\n")
    out = tmp_path / "bag"
    code = main(["make-bag", str(scene), str(out)])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "calib.txt has a malformed cam0, cam1 or baseline" in err
    assert nothing_written(out)


def test_malformed_ground_truth_index_is_one_error_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    bags = tmp_path / "bags"
    shutil.copytree(BAGS, bags)
    (bags / "middlebury_gt" / "index.yaml").write_text("gt_scale: 64\nframes:\n  - {stamp_ns: 1}\n")
    code = main(["demo", "--bags", str(bags), "--out", str(tmp_path / "out"), "--set", "disparity_range=16"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "not a ground-truth index (KeyError" in err


def test_a_parser_message_with_newlines_still_makes_one_error_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("- : [\n")  # PyYAML's message quotes the line with a caret under it
    code = main(["process", str(MIDDLEBURY_BAG), str(tmp_path / "out"), "--params", str(params)])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("ERROR: ") and err.count("\n") == 1, err
    assert "cannot read it as YAML" in err
