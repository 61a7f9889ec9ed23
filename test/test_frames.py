"""The FrameStream's order of a frame's two stages, on the bundled EuRoC bag read by name (StereoSet)."""

from __future__ import annotations

from pathlib import Path

from stereo_depth.bag.reader import StereoBagReader
from stereo_depth.bag.types import rosbags_types
from stereo_depth.core.params import make_params
from stereo_depth.frames import CloudJob, FrameStream
from stereo_depth.options import OutputOptions

EUROC_BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"


def test_images_come_back_at_once_and_a_cloud_job_only_for_due_clouds() -> None:
    """As stereo_node runs it: the cloud job is handed to another runner (here: kept for later), and
    points_max_rate (here one cloud per 1000 s) leaves the other frames without one."""
    output = OutputOptions(points_max_rate=0.001)
    events: list[tuple[int, str, list[str]]] = []
    later: list[CloudJob] = []
    with StereoBagReader(EUROC_BAG) as reader:
        stream = FrameStream(rosbags_types(), make_params(), output, names=reader.topics.input_names)
        for inputs in reader.frames():
            out = stream.match(inputs, ("disparity", "points2"))
            events.append((inputs.stamp_ns, "images", sorted(out.images)))
            if out.cloud is not None:
                later.append(out.cloud)
    stamps = sorted({stamp for stamp, _, _ in events})
    assert len(stamps) == 6 and len(later) == 1
    assert events == [(stamp, "images", ["disparity"]) for stamp in stamps]
    cloud = later[0].run()
    assert later[0].frame.stamp_ns == stamps[0]
    assert sorted(cloud.messages) == ["points2"]


def test_calibration_changed_is_returned_with_the_first_frame_of_a_calibration() -> None:
    """The stream says which frame came with a new calibration: the first frame of the bag, none after."""
    with StereoBagReader(EUROC_BAG) as reader:
        stream = FrameStream(rosbags_types(), make_params(), names=reader.topics.input_names)
        changed = [stream.match(inputs, ("disparity",)).calibration_changed for inputs in reader.frames()]
    assert changed == [True] + [False] * (len(changed) - 1)
