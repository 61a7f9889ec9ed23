"""`stereo-depth calibrate`: chessboard pairs (a folder or a bag) -> left.yaml, right.yaml, report, picture."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from stereo_depth.atomic_output import AtomicFolder
from stereo_depth.commands.common import add_topic_options, topic_choice
from stereo_depth.core.calibration import (
    MIN_VIEWS,
    Board,
    ImagePair,
    StereoCalibration,
    Views,
    calibrate_stereo,
    detect_views,
    make_report,
    side_by_side,
)
from stereo_depth.core.camera import StereoCamera
from stereo_depth.errors import CalibrationError
from stereo_depth.formats.camera_info_yaml import camera_info_to_yaml

if TYPE_CHECKING:
    from stereo_depth.bag.reader import TopicChoice

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
PICTURE = "rectified.png"
OUTPUTS = ("left.yaml", "right.yaml", "report.txt", PICTURE)  # everything --out DIR holds


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "calibrate",
        help="calibrate a stereo pair from chessboard views into camera_info YAML files",
        description=(
            "INPUT is a folder with leftNN/rightNN images (png/jpg, paired by the rest of the name), a folder "
            "with left/ and right/ subfolders (paired by file name), or a bag (rosbag2 folder or ROS 1 .bag "
            "file) with a stereo pair of image topics (--left/--right if its names are unusual). Writes "
            "DIR/left.yaml and DIR/right.yaml (load them with a driver's "
            f"camera_info_url), DIR/report.txt and DIR/{PICTURE}; on any error writes nothing."
        ),
    )
    parser.add_argument("input", type=Path, metavar="INPUT")
    parser.add_argument("--board", required=True, metavar="COLSxROWS", help="inner corners, e.g. 9x6")
    parser.add_argument("--square", required=True, type=float, metavar="METRES", help="square edge, e.g. 0.025")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR")
    parser.add_argument("--min-views", type=int, default=MIN_VIEWS, help="fewest usable pairs (default %(default)s)")
    parser.add_argument("--every", type=int, default=1, metavar="N", help="bag input: use every Nth frame (default 1)")
    parser.add_argument("--left-name", default="left", help="camera_name in left.yaml (default %(default)s)")
    parser.add_argument("--right-name", default="right", help="camera_name in right.yaml (default %(default)s)")
    add_topic_options(parser, with_calibration=False)
    parser.set_defaults(run=run)


def parse_board(text: str, square: float) -> Board:
    cols, sep, rows = text.lower().partition("x")
    if not sep or not cols.isdigit() or not rows.isdigit():
        msg = f"--board expects COLSxROWS inner corners, e.g. 9x6; got '{text}'"
        raise CalibrationError(msg)
    return Board(int(cols), int(rows), square)


def _images_by_key(paths: list[Path], prefix: str) -> dict[str, Path]:
    return {p.name[len(prefix) :].rsplit(".", 1)[0]: p for p in paths if p.suffix.lower() in IMAGE_SUFFIXES}


def folder_pairs(folder: Path) -> list[tuple[str, Path, Path]]:
    """(name, left, right) paths, sorted; a picture without its partner is an error, not a skipped view."""
    if (folder / "left").is_dir() and (folder / "right").is_dir():
        left = _images_by_key(sorted((folder / "left").iterdir()), "")
        right = _images_by_key(sorted((folder / "right").iterdir()), "")
    else:
        left = _images_by_key(sorted(folder.glob("left*")), "left")
        right = _images_by_key(sorted(folder.glob("right*")), "right")
    if not left and not right:
        msg = f"{folder}: no left*/right* images (png, jpg) and no left/ and right/ folders"
        raise CalibrationError(msg)
    unpaired = sorted(str(p.name) for k, p in (left | right).items() if k not in left or k not in right)
    if unpaired:
        msg = f"{folder}: no partner for {', '.join(unpaired)}; every left image needs the right one of the same name"
        raise CalibrationError(msg)
    return [(key, left[key], right[key]) for key in sorted(left)]


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        msg = f"cannot read image {path}"
        raise CalibrationError(msg)
    return image


def folder_images(folder: Path) -> Iterator[ImagePair]:
    for _, left, right in folder_pairs(folder):
        yield ImagePair(f"{left.name}/{right.name}", _read(left), _read(right))


def bag_images(path: Path, choice: TopicChoice, every: int) -> Iterator[ImagePair]:
    """Every Nth stereo frame of a bag; rosbags is imported only when a bag is read. The images only:
    a bag being calibrated needs no camera_info."""
    from stereo_depth.bag.reader import StereoBagReader
    from stereo_depth.frames import decode_image

    with StereoBagReader(path, choice=choice) as reader:
        for index, frame in enumerate(reader.frames()):
            if index % every == 0:
                left, right = decode_image(frame.left_image), decode_image(frame.right_image)
                yield ImagePair(f"stamp {frame.stamp_ns}", left, right)


def input_images(args: argparse.Namespace) -> Iterator[ImagePair]:
    if args.input.is_file() and args.input.suffix == ".bag":
        return bag_images(args.input, images_only(args), args.every)
    if not args.input.is_dir():
        msg = f"{args.input}: not a folder; pass a folder of image pairs, a rosbag2 folder or a ROS 1 .bag file"
        raise CalibrationError(msg)
    if (args.input / "metadata.yaml").is_file():
        return bag_images(args.input, images_only(args), args.every)
    return folder_images(args.input)


def images_only(args: argparse.Namespace) -> TopicChoice:
    """The topics to calibrate from; any camera_info in the bag is what is being replaced, so not needed."""
    return topic_choice(args, need_info=False)


def picture(views: Views, result: StereoCalibration) -> np.ndarray:
    """The first usable pair, rectified through the written calibration, side by side with row lines."""
    assert views.sample is not None  # calibrate_stereo refused an empty set of views
    camera = StereoCamera(result.left, result.right)
    return side_by_side(camera.rectify(views.sample.left, "left"), camera.rectify(views.sample.right, "right"))


def write_outputs(out: Path, files: dict[str, bytes]) -> None:
    """All files appear together or none: `out` is replaced as a whole folder, so it may hold only
    what an earlier calibration wrote (checked before any work, in `_check_args`)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with AtomicFolder(out, overwrite=True) as staging:
        staging.mkdir()
        for name, data in files.items():
            (staging / name).write_bytes(data)


def _check_args(args: argparse.Namespace) -> Board:
    board = parse_board(args.board, args.square)
    if args.out.exists() and not args.out.is_dir():
        msg = f"--out {args.out} is a file; pass a folder"
        raise CalibrationError(msg)
    foreign = sorted(p.name for p in args.out.iterdir() if p.name not in OUTPUTS) if args.out.is_dir() else []
    if foreign:
        msg = (
            f"--out {args.out} holds other files ({', '.join(foreign[:5])}); the calibration replaces the whole "
            "folder, so pass a new folder or one that holds only an earlier calibration"
        )
        raise CalibrationError(msg)
    if args.every < 1 or args.min_views < 1:
        msg = "--every and --min-views must be at least 1"
        raise CalibrationError(msg)
    return board


def run(args: argparse.Namespace) -> int:
    board = _check_args(args)
    views = detect_views(input_images(args), board)
    result = calibrate_stereo(views, board, args.min_views)
    report = make_report(views, result)
    header = f"stereo-depth calibrate {args.input}: board {board.cols}x{board.rows}, square {board.square} m\n"
    ok, png = cv2.imencode(".png", picture(views, result))
    if not ok:
        msg = "could not encode the rectified picture as PNG"
        raise CalibrationError(msg)
    write_outputs(
        args.out,
        {
            "left.yaml": camera_info_to_yaml(result.left, args.left_name).encode(),
            "right.yaml": camera_info_to_yaml(result.right, args.right_name).encode(),
            "report.txt": (header + report.text()).encode(),
            PICTURE: png.tobytes(),
        },
    )
    print(header + report.text(), end="")
    print(f"wrote {args.out}/left.yaml, right.yaml, report.txt, {PICTURE}")
    return 0
