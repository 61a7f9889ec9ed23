"""`stereo-depth process --shard-seconds`: recording gaps at and after a shard border, longer than a
shard reader's read-ahead, with the frame before the gap waiting for a lost camera_info. Sharded and one
pass write the same frames; the merge of the parts refuses a frame written twice.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from stereo_depth.bag.recording import open_reader
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.errors import BagError
from stereo_depth.fleet.shards import merge

from conftest import SCENES

FAST = ["--profile", "fast", "--set", "disparity_range=16", "--outputs", "disparity"]
START_NS = 1_700_000_000 * 10**9


def tenths(first: int, last: int) -> list[int]:
    """Stamps at 10 Hz from `first` to `last` tenths of a second after the recording's start."""
    return [START_NS + k * 100_000_000 for k in range(first, last + 1)]


# (frame stamps, the frame whose right camera_info is lost, --jobs), with 2 s shards: borders at 2, 4, 6 s
GAPS = {
    # the frame on the 4 s border waits for its camera_info; the recording pauses until 6.1 s, past the
    # 2-4 s shard's 2 s read-ahead (before the fix, that frame was written by two shards)
    "on_a_border": ([*tenths(0, 40), *tenths(61, 65)], 40, "2"),
    "just_before_a_border": ([*tenths(0, 39), *tenths(62, 66)], 39, "1"),
    "after_a_border": ([*tenths(0, 45), *tenths(87, 91)], 45, "1"),
}


def stamps(bag: Path, topic: str) -> list[int]:
    reader = open_reader(bag)
    try:
        return [t for c, t, _ in reader.messages(reader.connections) if c.topic == topic]
    finally:
        reader.close()


def gap_bag(folder: Path, frame_stamps: list[int], lost_info: int) -> Path:
    """Real images (a crop of one Middlebury scene) stamped as given; frame `lost_info` (an index) has
    no right camera_info."""
    source = folder / "frames"
    for side in ("left", "right"):
        (source / side).mkdir(parents=True)
        for stamp in frame_stamps:
            (source / side / f"{stamp}.png").symlink_to(SCENES / "artl" / f"{side}.png")
    (source / "calib.txt").symlink_to(SCENES / "artl" / "calib.txt")
    full = folder / "full"
    assert main(["make-bag", str(source), str(full), "--crop", "160x120"]) == 0
    bag = folder / "bags" / "gap"  # alone in its folder
    bag.parent.mkdir()
    reader = open_reader(full)
    try:
        with BagWriter(bag, compress=False) as writer:
            for connection, log_time, raw in reader.messages(reader.connections):
                if not (connection.topic.endswith("right/camera_info") and log_time == frame_stamps[lost_info]):
                    writer.write_raw(connection.topic, connection.msgtype, raw, log_time)
    finally:
        reader.close()
    return bag


@pytest.mark.parametrize("gap", GAPS)
def test_a_gap_at_or_after_a_shard_border_writes_each_frame_once_as_one_pass_does(tmp_path: Path, gap: str) -> None:
    frame_stamps, lost_info, jobs = GAPS[gap]
    bag = gap_bag(tmp_path, frame_stamps, lost_info)
    assert main(["process", str(bag), str(tmp_path / "one_pass"), *FAST]) == 0
    one_pass = stamps(tmp_path / "one_pass", "/stereo/disparity")
    assert one_pass == frame_stamps  # the frame without its camera_info took the one before

    out = tmp_path / "sharded"
    assert main(["process", str(bag), "--out-dir", str(out), "--jobs", jobs, "--shard-seconds", "2", *FAST]) == 0
    assert stamps(out / "gap", "/stereo/disparity") == one_pass


def test_the_merge_refuses_a_frame_that_two_parts_wrote(tmp_path: Path) -> None:
    part = tmp_path / "part"
    assert main(["make-bag", str(SCENES / "artl"), str(part), "--crop", "160x120"]) == 0
    out = tmp_path / "merged"
    with pytest.raises(BagError, match="twice"):
        merge([part, part], out, storage="mcap", compress=False, overwrite=False, custom_data={})
    assert not out.exists()
