"""frames.py's sequence of a frame's two stages, on the bundled EuRoC bag read by name (StereoSet)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from stereo_depth.bag.reader import StereoBagReader
from stereo_depth.bag.types import rosbags_types
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.frames import Geometry, OutputState, decode_frame, frame_outputs, match_frame
from stereo_depth.options import OutputOptions

EUROC_BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"


def test_images_go_out_first_and_the_cloud_stage_runs_only_for_due_clouds() -> None:
    """As stereo_node runs it: the cloud stage is handed to another runner (here: kept for later), and
    points_max_rate (here one cloud per 1000 s) leaves the other frames without one."""
    params, output = make_params(), OutputOptions(points_max_rate=0.001)
    pipeline, state = StereoPipeline(params), OutputState()
    events: list[tuple[int, str, list[str]]] = []
    later: list[Callable[[], None]] = []
    with StereoBagReader(EUROC_BAG) as reader:
        names = reader.topics.input_names
        for inputs in reader.frames():
            frame = decode_frame(inputs, pipeline, output, rectified=False, names=names)
            result = match_frame(pipeline, frame, names)

            def images(messages: dict[str, Any], stamp: int = inputs.stamp_ns) -> None:
                events.append((stamp, "images", sorted(messages)))

            def cloud(messages: dict[str, Any], geometry: Geometry | None, stamp: int = inputs.stamp_ns) -> None:
                assert (geometry is None) == (not messages)
                events.append((stamp, "cloud", sorted(messages)))

            wanted = ("disparity", "points2")
            stage = (rosbags_types(), pipeline, frame, result, params, output, wanted, state, images, cloud)
            frame_outputs(*stage, run_cloud_stage=later.append)
    stamps = sorted({stamp for stamp, _, _ in events})
    assert len(stamps) == 6 and len(later) == 1
    first, rest = stamps[0], stamps[1:]
    expected = [(first, "images", ["disparity"])]
    for stamp in rest:
        expected += [(stamp, "images", ["disparity"]), (stamp, "cloud", [])]
    assert events == expected
    later[0]()
    assert events[-1] == (first, "cloud", ["points2"])
