"""`stereo-depth process IN... --out-dir DIR`: many bags on Ray or local workers, resumable, and long
bags cut into shards, each output equal message for message to the one-bag run of the same input.

One `ray start --head` process on 127.0.0.1 serves the tests that join a cluster by address; one test
starts its own local instance as `--ray` alone does.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from waiting import wait_until

from stereo_depth.bag.process import ProcessOptions
from stereo_depth.bag.recording import open_reader
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.core.params import make_params
from stereo_depth.core.temporal import lead_in_frames
from stereo_depth.fleet.tasks import STOPPED, Task, run_task

from conftest import SCENES, euroc_sequence

BAGS = Path(__file__).resolve().parents[1] / "bags"
FAST = ["--profile", "fast", "--set", "disparity_range=16", "--outputs", "disparity", "depth"]
GOOD = ("euroc_raw", "middlebury", "artl")

Message = tuple[str, str, int, bytes]


def messages(bag: Path) -> list[Message]:
    """(topic, type, log time, CDR bytes) of every message, in the order the bag holds them."""
    reader = open_reader(bag)
    try:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages(connections=reader.connections)]
    finally:
        reader.close()


def hidden_leftovers(out_dir: Path) -> list[Path]:
    return [p for p in out_dir.iterdir() if p.name.startswith(".")]


def make_bag(out: Path, *sources: Path, rate: float = 10.0) -> Path:
    assert main(["make-bag", *map(str, sources), str(out), "--rate", str(rate)]) == 0
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of three real bags and one whose compressed chunk is zeroed part-way (it opens, then fails)."""
    folder = tmp_path_factory.mktemp("inputs")
    for name in GOOD[:2]:
        shutil.copytree(BAGS / name, folder / name)
    make_bag(folder / "artl", *[SCENES / "artl"] * 3)
    shutil.copytree(BAGS / "euroc_raw", folder / "damaged")
    storage = folder / "damaged" / "euroc_raw.mcap"
    data = bytearray(storage.read_bytes())
    data[int(len(data) * 0.4) : int(len(data) * 0.4) + 4096] = bytes(4096)
    storage.write_bytes(bytes(data))
    return folder


@pytest.fixture(scope="module")
def one_bag_outputs(inputs: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Message]]:
    """Each good input through the one-bag form: what every fleet output must equal."""
    out = tmp_path_factory.mktemp("single")
    for name in GOOD:
        assert main(["process", str(inputs / name), str(out / name), *FAST]) == 0
    return {name: messages(out / name) for name in GOOD}


FIXED_RAY_PORTS = (  # the client server (10001) starts only with ray[client], not installed here
    "dashboard-agent-listen",
    "dashboard-agent-grpc",
    "runtime-env-agent",
    "metrics-export",
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module", autouse=True)
def worker_settings() -> Iterator[None]:
    """Ray on loopback for tests: no token file written to ~/.ray (which a later head would then
    demand), no usage statistics. Workers (Ray's and the local pool's inherit this environment) run
    OpenCV on one thread each, so two of them leave the test files running beside this one some CPU;
    numba's count each worker sets itself (fleet/backends.py). NUMBA_NUM_THREADS is not changed here:
    numba in this process reads it again at each compile and refuses a value other than the one its
    threads started with ("Cannot set NUMBA_NUM_THREADS ... once the threads have been launched")."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RAY_AUTH_MODE", "disabled")
        patch.setenv("RAY_USAGE_STATS_ENABLED", "0")
        patch.setenv("OPENCV_FOR_THREADS_NUM", "1")
        yield


@pytest.fixture(scope="module")
def ray_head(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A Ray cluster head as `ray start --head` makes one, on loopback; stopped with its processes after."""
    pytest.importorskip("ray")
    port = free_port()
    temp_dir = Path(f"/tmp/ray_sd_{os.getpid()}")  # short: Ray's socket paths must fit 107 bytes
    env = dict(os.environ)
    ray = Path(sys.executable).parent / "ray"
    command = [str(ray), "start", "--head", "--block", f"--port={port}", "--node-ip-address=127.0.0.1"]
    command += ["--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp_dir}"]
    # Ray's fixed default ports (dashboard agent 52365, ...) would collide with another run's head on this
    # host: free ones instead
    command += [f"--{name}-port={free_port()}" for name in FIXED_RAY_PORTS]
    log = tmp_path_factory.mktemp("ray") / "head.log"
    with log.open("w") as sink:
        head = subprocess.Popen(command, env=env, stdout=sink, stderr=subprocess.STDOUT)
    try:
        wait_until(lambda: "block forever" in log.read_text() or head.poll() is not None, "the Ray head", 60.0, 0.2)
        assert head.poll() is None, log.read_text()
        yield f"127.0.0.1:{port}"
    finally:
        head.send_signal(signal.SIGTERM)  # --block: the head stops every process it started
        head.wait(timeout=30)
        shutil.rmtree(temp_dir, ignore_errors=True)


def run_fleet(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, list[str], str]:
    """Exit code, ERROR lines and stdout of one fleet run in this process."""
    return main_errors(capsys, "process", *args, *FAST)


def main_errors(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, list[str], str]:
    code = main(list(args))
    captured = capsys.readouterr()
    return code, [line for line in captured.err.splitlines() if line.startswith("ERROR:")], captured.out


def test_bags_on_a_ray_cluster_equal_one_bag_runs_and_a_damaged_one_is_reported(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    inputs: Path,
    one_bag_outputs: dict[str, list[Message]],
    ray_head: str,
) -> None:
    out, report = tmp_path / "out", tmp_path / "report.json"
    code, errors, _ = run_fleet(capsys, str(inputs), "--out-dir", str(out), "--ray", ray_head, "--report", str(report))
    assert code == 1
    assert len(errors) == 1 and str(inputs / "damaged") in errors[0] and "damaged" in errors[0], errors
    assert sorted(p.name for p in out.iterdir()) == sorted(GOOD)  # no partial output, no hidden folder
    for name in GOOD:
        assert messages(out / name) == one_bag_outputs[name], name
    bags = {Path(b["input"]).name: b for b in json.loads(report.read_text())["bags"]}
    assert bags["damaged"]["status"] == "failed" and "cannot read messages" in bags["damaged"]["error"]
    for name in GOOD:
        frames = len(one_bag_outputs[name]) // 2  # two outputs per frame
        assert bags[name]["status"] == "done" and bags[name]["frames_out"] == frames and bags[name]["error"] is None

    # A second run (on local workers this time) skips what is finished, leaving it untouched.
    stamps = {name: (out / name / "metadata.yaml").stat().st_mtime_ns for name in GOOD}
    code, errors, printed = run_fleet(
        capsys, str(inputs), "--out-dir", str(out), "--jobs", "1", "--report", str(report)
    )
    assert code == 1 and len(errors) == 1 and "damaged" in errors[0]
    assert "3 skipped" in printed
    assert {name: (out / name / "metadata.yaml").stat().st_mtime_ns for name in GOOD} == stamps
    assert {b["status"] for b in json.loads(report.read_text())["bags"]} == {"skipped", "failed"}

    # Other parameters are not "finished": the run refuses to replace them unless told to.
    other = ("--set", "correlation_window_size=5")
    code, errors, _ = run_fleet(capsys, str(inputs / "artl"), "--out-dir", str(out), *other)
    assert code == 1 and len(errors) == 1 and "made with other parameters" in errors[0] and "--overwrite" in errors[0]
    assert messages(out / "artl") == one_bag_outputs["artl"]
    code, errors, _ = run_fleet(capsys, str(inputs / "artl"), "--out-dir", str(out), *other, "--overwrite")
    assert code == 0, errors
    assert messages(out / "artl") != one_bag_outputs["artl"] and hidden_leftovers(out) == []

    # Other outputs, or compression, are other parameters too: refused, never skipped as finished.
    for changed in (("--outputs", "disparity"), ("--compress",)):
        code, errors, _ = main_errors(
            capsys, "process", str(inputs / "middlebury"), "--out-dir", str(out), *FAST, *changed
        )
        assert code == 1 and len(errors) == 1 and "made with other parameters" in errors[0], (changed, errors)
        assert messages(out / "middlebury") == one_bag_outputs["middlebury"]


@pytest.fixture(scope="module")
def long_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """40 frames at 10 Hz whose pairing is hard at 1 s borders: the right camera's messages recorded
    150 ms late (sets complete after a border), the right image before the 1 s border and the left
    image on the 2 s border missing (one pass leaves those two frames unpaired)."""
    plain = make_bag(tmp_path_factory.mktemp("plain") / "plain", *[SCENES / "artl"] * 40)
    start = min(t for _, _, t, _ in messages(plain))
    records = []
    for topic, msgtype, stamp, raw in messages(plain):
        frame = round((stamp - start) / 1e8)
        if (frame == 9 and topic.endswith("right/image_raw")) or (frame == 20 and topic.endswith("left/image_raw")):
            continue
        records.append((stamp + (150_000_000 if "/right/" in topic else 0), topic, msgtype, raw))
    bag = tmp_path_factory.mktemp("long") / "long"  # alone in its folder
    with BagWriter(bag, compress=False) as writer:
        for log_time, topic, msgtype, raw in sorted(records, key=lambda r: r[0]):
            writer.write_raw(topic, msgtype, raw, log_time)
    return bag


@pytest.fixture(scope="module")
def long_one_pass(long_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> list[Message]:
    one_pass = tmp_path_factory.mktemp("one_pass") / "long"
    assert main(["process", str(long_bag), str(one_pass), *FAST]) == 0
    expected = messages(one_pass)
    assert len(expected) == 2 * 38  # two frames have no partner
    return expected


def test_a_sharded_long_bag_equals_one_pass_on_a_local_ray_instance(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, long_bag: Path, long_one_pass: list[Message]
) -> None:
    pytest.importorskip("ray")

    out, report = tmp_path / "out", tmp_path / "report.json"
    code, errors, _ = run_fleet(
        capsys, str(long_bag), "--out-dir", str(out), "--shard-seconds", "1", "--ray", "--report", str(report)
    )
    assert code == 0, errors
    assert messages(out / "long") == long_one_pass
    (bag,) = json.loads(report.read_text())["bags"]
    assert bag["shards"] == 5 and bag["frames_in"] == 39 and bag["frames_out"] == 38
    assert hidden_leftovers(out) == []


def test_shards_on_local_workers_equal_one_pass_and_the_output_folder_is_not_an_input(
    capsys: pytest.CaptureFixture[str], long_bag: Path, long_one_pass: list[Message]
) -> None:
    out = long_bag.parent / "fleet_out"  # inside the input folder: its bags are outputs, not inputs
    for _ in range(2):  # the second run finds the first one's output and skips it
        code, errors, printed = run_fleet(
            capsys, str(long_bag.parent), "--out-dir", str(out), "--jobs", "2", "--shard-seconds", "0.7"
        )
        assert code == 0, errors
    assert "1 skipped" in printed
    assert messages(out / "long") == long_one_pass


@pytest.mark.parametrize(
    ("sig", "backend"),
    [(signal.SIGINT, "local"), (signal.SIGTERM, "local"), (signal.SIGINT, "ray")],
    ids=["Ctrl-C", "SIGTERM", "Ctrl-C on Ray"],
)
def test_local_workers_shard_and_ctrl_c_leaves_no_partial_output(
    request: pytest.FixtureRequest, tmp_path: Path, long_bag: Path, sig: signal.Signals, backend: str
) -> None:
    """Ctrl-C or a `kill` while two local workers (or Ray tasks, cancelled) write shards: exit 130, the
    output folder holds nothing."""
    out = tmp_path / "out"
    command = [sys.executable, "-m", "stereo_depth.cli", "process", str(long_bag), "--out-dir", str(out)]
    workers = ["--jobs", "2"] if backend == "local" else ["--ray", request.getfixturevalue("ray_head")]
    command += [*workers, "--shard-seconds", "0.5", "--profile", "quality"]
    run = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)  # environment: worker_settings
    assert run.stderr is not None
    shards = out / ".long.shards"
    wait_until(
        lambda: run.poll() is not None or any(p.name.startswith(".0") for p in shards.glob("*")), "a shard", 60.0
    )
    assert run.poll() is None, run.stderr.read()  # a shard is being written
    run.send_signal(sig)
    assert run.wait(timeout=60) == 130, run.stderr.read()
    assert "ERROR: interrupted" in run.stderr.read()
    assert list(out.iterdir()) == []


def test_missing_ray_is_one_clear_error(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed
    code, errors, _ = run_fleet(capsys, str(BAGS / "middlebury"), "--out-dir", str(tmp_path / "out"), "--ray")
    assert code == 1 and len(errors) == 1 and "pip install" in errors[0] and "ray" in errors[0]
    assert not (tmp_path / "out" / "middlebury").exists()


def test_shards_with_the_temporal_filter_equal_one_pass(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """The filter's state crosses shard borders: each shard is fed the frames before its first (lead-in)."""
    (tmp_path / "inputs").mkdir()
    bag = make_bag(tmp_path / "inputs" / "euroc", euroc_sequence(tmp_path / "sequence", 30))  # a moving camera
    temporal = ["--set", "temporal_filter=true", "--set", "fill_holes=false"]  # holes: the filter's to handle
    assert main(["process", str(bag), str(tmp_path / "one_pass"), *FAST, *temporal]) == 0
    out = tmp_path / "sharded"
    code, errors, _ = run_fleet(
        capsys, str(bag), "--out-dir", str(out), "--jobs", "2", "--shard-seconds", "0.7", *temporal
    )
    assert code == 0, errors
    one_pass = messages(tmp_path / "one_pass")
    assert len(one_pass) == 2 * 30
    assert messages(out / "euroc") == one_pass


def test_shards_read_back_as_many_frames_as_the_temporal_filter_looks_back_over(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A 30 Hz bag's second shard starts 138 frames in: its lead-in reaches back to the bag's start (the
    filter's presence counts up to 128 frames of a still view), so it equals one pass."""
    (tmp_path / "inputs").mkdir()
    bag = make_bag(tmp_path / "inputs" / "still", *[SCENES / "artl"] * (lead_in_frames() + 18), rate=30.0)
    temporal = ["--set", "temporal_filter=true", "--set", "fill_holes=false"]
    assert main(["process", str(bag), str(tmp_path / "one_pass"), *FAST, *temporal]) == 0
    out = tmp_path / "sharded"
    code, errors, _ = run_fleet(capsys, str(bag), "--out-dir", str(out), "--shard-seconds", "4.6", *FAST, *temporal)
    assert code == 0, errors
    assert messages(out / "still") == messages(tmp_path / "one_pass")


def test_shards_too_slow_for_the_temporal_filters_lead_in_are_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """At 2 Hz the lead-in, read back as for 10 Hz, holds 26 frames, not the 132 the filter needs: an
    error, not a different output."""
    (tmp_path / "inputs").mkdir()
    bag = make_bag(tmp_path / "inputs" / "slow", *[SCENES / "artl"] * 40, rate=2.0)
    temporal = ["--set", "temporal_filter=true", "--set", "fill_holes=false"]
    code, errors, _ = run_fleet(
        capsys, str(bag), "--out-dir", str(tmp_path / "out"), "--shard-seconds", "15", *FAST, *temporal
    )
    assert code == 1 and len(errors) == 1, errors
    assert f"needs {lead_in_frames()} frames before it" in errors[0], errors
    assert not (tmp_path / "out" / "slow").exists()


@pytest.mark.parametrize("when", ["before it starts", "between frames"])
def test_a_task_whose_stop_file_appears_stops_and_leaves_no_output(tmp_path: Path, long_bag: Path, when: str) -> None:
    """How an interrupted Ray run stops its tasks (not with ray.cancel, which can abort Ray's driver)."""
    out, stop = tmp_path / "out", tmp_path / ".stop"
    out.mkdir()
    task = Task("long", long_bag, out / "long", make_params(profile="quality"), ProcessOptions(), stop_file=stop)
    if when == "before it starts":
        stop.touch()
    else:  # once the task's hidden output folder holds a part written

        def stop_when_writing() -> None:
            wait_until(lambda: any(out.glob(".*/*")), "a part of the task's output", 120.0, 0.01)
            stop.touch()

        threading.Thread(target=stop_when_writing, daemon=True).start()
    result = run_task(task)
    assert result.error == STOPPED and result.frames_out == 0
    assert list(out.iterdir()) == []
