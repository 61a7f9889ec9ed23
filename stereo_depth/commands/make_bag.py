"""`stereo-depth make-bag`: scene folders, image sequences or EuRoC folders into a rosbag2."""

from __future__ import annotations

import argparse
from contextlib import ExitStack
from pathlib import Path

from stereo_depth.bag.ground_truth import GroundTruthWriter
from stereo_depth.bag.make import StreamLayout, parse_topic_overrides, write_stream
from stereo_depth.bag.reader import ROLES
from stereo_depth.bag.sources import crop, read_frames
from stereo_depth.bag.writer import ROS1, STORAGES, BagWriter, check_output
from stereo_depth.errors import BagError
from stereo_depth.messages import COMPRESSED_FORMATS


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "make-bag",
        help="build a stereo rosbag2 from scene folders, an image sequence or a EuRoC folder",
        description=(
            "Writes left/right image_raw and camera_info per frame. SOURCE is one or more scene folders "
            "(left.png, right.png, calib.txt), or one folder with left/ and right/ images paired by file "
            "name and a calibration (cam0_sensor.yaml + cam1_sensor.yaml, left.yaml + right.yaml, or calib.txt), "
            "or a EuRoC folder (mav0/cam0/data, mav0/cam0/sensor.yaml)."
        ),
    )
    parser.add_argument("sources", nargs="+", type=Path, metavar="SOURCE")
    parser.add_argument("out", type=Path, metavar="OUT_BAG")
    parser.add_argument(
        "--rate", type=float, help="restamp at this many frames/s (default: file-name stamps in ns, else 10)"
    )
    parser.add_argument(
        "--start", type=float, default=1.7e9, help="first stamp when restamping, seconds (default %(default).0f)"
    )
    parser.add_argument("--namespace", default="/stereo", help="namespace of the topics (default %(default)s)")
    parser.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="ROLE=NAME",
        help=f"rename one topic; ROLE is one of {', '.join(ROLES)}; a relative NAME goes under the namespace",
    )
    parser.add_argument("--frame-id", default="left_camera_optical_frame", help="left frame_id")
    parser.add_argument("--right-frame-id", default="right_camera_optical_frame", help="right frame_id")
    parser.add_argument("--crop", metavar="WxH", help="keep the centre WxH of every frame (K and P follow)")
    parser.add_argument("--gt", type=Path, metavar="DIR", help="write the scenes' ground truth here, keyed by stamp")
    parser.add_argument(
        "--storage",
        choices=sorted([*STORAGES, ROS1]),
        default="mcap",
        help="rosbag2 storage, or rosbag1 for a ROS 1 .bag file (OUT_BAG is then the file, e.g. out.bag)",
    )
    parser.add_argument(
        "--compress-images",
        choices=COMPRESSED_FORMATS,
        help="write images as sensor_msgs/CompressedImage on <image topic>/compressed, as image_transport does",
    )
    parser.add_argument(
        "--no-camera-info", action="store_true", help="write the images only, as EuRoC's bags (calibration in files)"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace OUT_BAG (and --gt DIR) if they exist")
    parser.set_defaults(run=run)


def parse_size(text: str) -> tuple[int, int]:
    width, sep, height = text.lower().partition("x")
    if not sep or not width.isdigit() or not height.isdigit() or not int(width) or not int(height):
        msg = f"--crop expects WIDTHxHEIGHT, e.g. 640x480; got '{text}'"
        raise BagError(msg)
    return int(width), int(height)


def run(args: argparse.Namespace) -> int:
    if args.rate is not None and not args.rate > 0:
        msg = f"--rate {args.rate} must be positive"
        raise BagError(msg)
    layout = StreamLayout(
        namespace=args.namespace,
        left_frame_id=args.frame_id,
        right_frame_id=args.right_frame_id,
        rate_hz=args.rate,
        start_ns=round(args.start * 1e9),
        overrides=parse_topic_overrides(args.topic),
        compress_images=args.compress_images,
        camera_info=not args.no_camera_info,
    )
    if args.storage == ROS1 and args.out.suffix != ".bag":
        msg = f"--storage rosbag1 writes a ROS 1 bag file: name it *.bag, not {args.out.name}"
        raise BagError(msg)
    size = parse_size(args.crop) if args.crop else None
    check_output(args.out, args.overwrite, is_file=args.storage == ROS1)
    if args.gt:
        check_output(args.gt, args.overwrite)
    frames = read_frames(args.sources)
    if size is not None:
        frames = (crop(frame, *size) for frame in frames)
    with ExitStack() as stack:
        writer = stack.enter_context(BagWriter(args.out, storage=args.storage, overwrite=args.overwrite))
        ground_truth = stack.enter_context(GroundTruthWriter(args.gt, overwrite=args.overwrite)) if args.gt else None
        count = write_stream(frames, writer, layout, ground_truth)
    print(f"wrote {count} frames to {args.out} ({', '.join(layout.written())})")
    if args.gt:
        print(f"ground truth for the frames that have it: {args.gt}")
    return 0
