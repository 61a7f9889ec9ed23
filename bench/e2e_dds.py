"""End to end over DDS: replayed frames -> stereo_node -> a monitor, each in its own process.

Measures what the ROS 1 stereo_image_proc anchor (a folder with its run.sh, passed as --anchor DIR) measures,
the same way, on the same kind of frames:
  * a publisher process replays the anchor's synthetic 640x480 / 1280x720 mono8 stream (bench/lib/anchor_frames.py,
    same recipe and seed; bgr8 copies for the colour cases) at a set rate: left/right image_raw + camera_info,
    reliable, pre-serialized, in the case's order within a frame (a driver may send camera_info first), with
    the right camera some frames late (skew) or frames sent back to back (bursts);
  * stereo_node runs in its own process (`python -m stereo_depth.nodes.stereo_node`, namespace /stereo);
  * a monitor process subscribes to left/image_raw, disparity and points2 (reliable, raw CDR so that
    10 MB clouds cost it no deserialization) and logs every receipt with DDS's reception time;
  * latency: from the publisher's send time of the frame's last message (one clock on one machine), and from
    the monitor's receipt of left/image_raw with the same stamp;
    rate = outputs / (last - first receipt); dropped = replayed frames with no output;
    node CPU = utime + stime of the stereo_node process over the active window (100% = 1 core);
  * bare_vga_30: no node; the publisher sends messages of the disparity's and the cloud's sizes at 30 Hz
    straight to the monitor: what bare rclpy reaches for such messages in the same run.
A few warm-up frames (not counted) go first, so one-off start-up work (imports, loading numba's cache,
first allocation) is not billed to the stream; numba's kernels are compiled before the first case
(`stereo-depth compile`). Every process it starts is stopped by PID.

`--anchor DIR` runs the C++ anchor (DIR/run.sh: ROS 1 stereo_image_proc, rosbag play, a roscpp monitor; it
installs Debian's ROS 1 packages on first use) once after each of our runs of a case it has, so the two
interleave on a shared machine (ours, anchor, ours, anchor), and prints both side by side as medians.
The anchor talks TCPROS: the Fast DDS profile does not apply to it, so its row stands beside both of ours.

All processes get ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and ROS_DOMAIN_ID (default: a free one,
locked). `--profiles all` exports the repository's Fast DDS profile (config/fastdds_large_images.xml) in
all three; `none` in none, as a new user runs it (stereo_node then loads it for itself, see
stereo_depth/ros/transport.py).

    .venv/bin/python bench/e2e_dds.py                 # every case once, profile exported
    .venv/bin/python bench/e2e_dds.py --pairing       # publish orders, skew, bursts, bare rclpy; none and all
    .venv/bin/python bench/e2e_dds.py --repeats 3 --cases bm_vga_30 sgbm_vga_30 bm_720p_30
    .venv/bin/python bench/e2e_dds.py --timeline --cases bm_vga_30_disparity_only   # where the latency goes,
        # and the share of frames DDS repaired an input of on its way to the node or to the monitor
    .venv/bin/python bench/e2e_dds.py --anchor DIR --repeats 3 --profiles none all \
        --cases bm_vga_30 bm_vga_30_disparity_only     # the C++ chain interleaved with ours
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from lib.domain_lock import isolate_on_this_host

from stereo_depth.machine import print_machine
from stereo_depth.ros.transport import PROFILE_VARIABLES

REPO = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
TICK = os.sysconf("SC_CLK_TCK")
NAMESPACE = "/e2e_dds"  # not /stereo, which test_replay and most launch files use
FIRST_STAMP_NS = 1_700_000_000 * 10**9
WARMUP_FRAMES = 10


@dataclass(frozen=True)
class Case:
    name: str
    width: int
    height: int
    rate_hz: float
    params: tuple[str, ...]  # stereo_node -p name:=value
    points: bool = True  # the monitor subscribes to points2
    order: str = "0123"  # publish order within a frame: 0 left image, 1 left info, 2 right image, 3 right info
    skew: int = 0  # the right camera's messages of frame i go out with the left camera's of frame i + skew
    burst: int = 1  # frames sent back to back, every burst-th period (a driver that buffers)
    color: bool = False  # bgr8 images (921 KB at VGA) instead of mono8
    bare: bool = False  # no stereo_node: the publisher sends disparity- and points2-sized messages itself


ANCHOR = ("profile:=stereo_image_proc",)  # BM, 64 disparities, window 15: the anchor's defaults
# ROS 1 stereo_image_proc packs x, y, z, rgb into 16 bytes a point; ROS 2's default (and ours) pads to 32.
SAME_CLOUD = ("avoid_point_cloud_padding:=true",)
CASES = {
    c.name: c
    for c in (
        Case("fast_vga_15", 640, 480, 15.0, ("profile:=fast",)),
        Case("quality_vga_30_128", 640, 480, 30.0, ("profile:=quality", "disparity_range:=128")),
        Case("default_vga_30_128", 640, 480, 30.0, ("profile:=default", "disparity_range:=128")),
        Case("fast_vga_30", 640, 480, 30.0, ("profile:=fast",)),
        Case("fast_vga_60", 640, 480, 60.0, ("profile:=fast",)),
        Case("fast_vga_30_processed", 640, 480, 30.0, ("profile:=fast", "downsample_output:=processed")),
        Case("bm_vga_30", 640, 480, 30.0, ANCHOR),
        Case("bm_vga_30_16b", 640, 480, 30.0, (*ANCHOR, *SAME_CLOUD)),
        Case("bm_vga_30_disparity_only", 640, 480, 30.0, ANCHOR, points=False),
        Case("bm_vga_90", 640, 480, 90.0, ANCHOR),
        Case("sgbm_vga_30", 640, 480, 30.0, (*ANCHOR, "stereo_algorithm:=1")),
        Case("sgbm_vga_30_16b", 640, 480, 30.0, (*ANCHOR, "stereo_algorithm:=1", *SAME_CLOUD)),
        Case("bm_720p_30", 1280, 720, 30.0, ANCHOR),
        Case("bm_720p_30_16b", 1280, 720, 30.0, (*ANCHOR, *SAME_CLOUD)),
        # input pairing: the order and timing of the four topics must not matter
        Case("bm_vga_30_info_first", 640, 480, 30.0, ANCHOR, order="1302"),
        Case("bm_vga_30_bgr8_info_first", 640, 480, 30.0, ANCHOR, order="1302", color=True),
        Case("bm_vga_30_bgr8", 640, 480, 30.0, ANCHOR, color=True),
        Case("bm_vga_30_right_2_late", 640, 480, 30.0, ANCHOR, order="1302", skew=2),
        # bursts: 3 waiting places (max_waiting_frames), so the newest-set-only default does not drop 2 of 3
        Case("bm_vga_30_bursts_of_3", 640, 480, 30.0, (*ANCHOR, "max_waiting_frames:=3"), order="1302", burst=3),
        # bare rclpy: messages of the disparity's and points2's sizes at 30 Hz, publisher -> monitor
        Case("bare_vga_30", 640, 480, 30.0, (), bare=True),
    )
}
PAIRING = [
    "bare_vga_30",
    "bm_vga_30_info_first",
    "bm_vga_30",
    "bm_vga_30_bgr8_info_first",
    "bm_vga_30_right_2_late",
    "bm_vga_30_bursts_of_3",
]
ANCHOR_NAMES = {  # the anchor's case names, for the side-by-side table
    "bm_vga_30": "bm vga 1x",
    "bm_vga_30_16b": "bm vga 1x",
    "bm_vga_30_disparity_only": "bm vga 1x disparity-only",
    "bm_vga_90": "bm vga 3x",
    "sgbm_vga_30": "sgbm vga 1x",
    "sgbm_vga_30_16b": "sgbm vga 1x",
    "bm_720p_30": "bm hd720 1x",
    "bm_720p_30_16b": "bm hd720 1x",
}


def machine_line() -> str:
    """CPU model, widest SIMD level its flags offer, cores: what every figure here depends on."""
    info = Path("/proc/cpuinfo").read_text()
    model = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")), "?")
    flags = set(next((ln.split(":", 1)[1].split() for ln in info.splitlines() if ln.startswith("flags")), []))
    levels = (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"), ("sse4_2", "SSE4.2"), ("asimd", "NEON"))
    simd = next((name for flag, name in levels if flag in flags), platform.machine())
    return f"CPU {model}, SIMD {simd}, {os.cpu_count()} cores"


def run_anchor(folder: Path, name: str, args: argparse.Namespace, workdir: Path) -> dict[str, Any] | None:
    """One run of one anchor case (run.sh with REPEATS=1); its summary figures, None if it failed."""
    env = dict(os.environ, WORK=str(args.anchor_work), REPEATS="1", FRAMES=str(args.frames))
    env.update(CASES=name.replace(" ", "_"), HD="1" if "hd720" in name else "0")
    env.update(ROS_PORT=str(11311 + 100 + int(args.domain_id)))  # apart from other users' masters
    env["SKIP_INSTALL"] = "1" if (args.anchor_work / "sip_monitor").exists() else "0"
    log = workdir / f"anchor.{name.replace(' ', '_')}.log"
    with log.open("ab") as out:
        code = subprocess.call(["bash", str(folder / "run.sh")], env=env, stdout=out, stderr=subprocess.STDOUT)
    summary = args.anchor_work / "summary.json"
    if code != 0 or not summary.exists():
        print(f"anchor {name}: run.sh failed ({code}), see {log}", flush=True)
        return None
    figures: dict[str, Any] | None = json.loads(summary.read_text()).get(name)
    summary.unlink()
    return figures


def ros_env(domain_id: str, shm_profile: bool) -> dict[str, str]:
    """shm_profile False: no profile exported, as a new user runs it (stereo_node still loads its own)."""
    env = {k: v for k, v in os.environ.items() if k not in PROFILE_VARIABLES and k != "ROS_LOCALHOST_ONLY"}
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=domain_id, PYTHONUNBUFFERED="1")
    if shm_profile:
        profile = str(REPO / "config" / "fastdds_large_images.xml")
        env.update(FASTRTPS_DEFAULT_PROFILES_FILE=profile, FASTDDS_DEFAULT_PROFILES_FILE=profile)
    return env


# ------------------------------------------------------------------------------------------ publisher


def run_publisher(args: argparse.Namespace) -> None:
    """Pre-serialize every message, wait for the node and the monitor, then replay on an absolute schedule
    in the case's order, skew and bursts; the send time of each frame's last message goes to --sent."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CameraInfo, Image, PointCloud2
    from stereo_msgs.msg import DisparityImage

    from stereo_depth.messages import array_to_image, camera_info_to_msg, make_header
    from stereo_depth.ros.types import RCLPY_TYPES

    sys.path.insert(0, str(Path(__file__).parent))
    from lib.anchor_frames import FRAME_ID, camera_infos, frames

    rclpy.init()
    node = rclpy.create_node("e2e_replay")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    if args.bare:
        topics = [("disparity", DisparityImage), ("points2", PointCloud2)]
        wanted: tuple[int, ...] = (1, 1)
    else:
        topics = [("left/image_raw", Image), ("left/camera_info", CameraInfo)]
        topics += [("right/image_raw", Image), ("right/camera_info", CameraInfo)]
        wanted = (2, 1, 1, 1)  # left image: stereo_node + monitor
    pubs = [node.create_publisher(t, f"{NAMESPACE}/{name}", qos) for name, t in topics]
    infos = camera_infos(args.width, args.height)
    total = WARMUP_FRAMES + args.frames
    period_ns = round(1e9 / args.rate)
    sets: list[list[bytes]] = []
    for i, (left, right) in enumerate(frames(args.width, args.height, total)):
        header = make_header(RCLPY_TYPES, FIRST_STAMP_NS + (i - WARMUP_FRAMES) * period_ns, FRAME_ID)
        if args.bare:
            sets.append([serialize_message(m) for m in bare_messages(header, args.width, args.height)])
            continue
        if args.color:
            left, right = (np.repeat(image[:, :, None], 3, axis=2) for image in (left, right))
        msgs = [array_to_image(RCLPY_TYPES, header, left), camera_info_to_msg(RCLPY_TYPES, header, infos[0])]
        msgs += [array_to_image(RCLPY_TYPES, header, right), camera_info_to_msg(RCLPY_TYPES, header, infos[1])]
        sets.append([serialize_message(m) for m in msgs])
    deadline = time.monotonic() + 60
    while any(p.get_subscription_count() < n for p, n in zip(pubs, wanted, strict=True)):
        if time.monotonic() > deadline:
            sys.exit("publisher: stereo_node / monitor did not subscribe within 60 s")
        time.sleep(0.05)
    time.sleep(1.0)  # let both ends finish matching (reliable writers need the readers' acks)
    sent: dict[int, int] = {}
    start = time.monotonic() + 0.5
    for slot, sends in enumerate(schedule(len(sets), args)):
        if slot == WARMUP_FRAMES:
            time.sleep(2.0)
            start = time.monotonic() - slot / args.rate
        delay = start + slot / args.rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        for frame, index in sends:
            sent[frame] = time.time_ns()  # ends as the send time of the frame's last message
            pubs[index].publish(sets[frame][index])
    time.sleep(0.5)
    Path(args.sent).write_text(
        json.dumps({str(FIRST_STAMP_NS + (f - WARMUP_FRAMES) * period_ns): t for f, t in sent.items()})
    )
    node.destroy_node()
    rclpy.try_shutdown()


def schedule(count: int, args: argparse.Namespace) -> list[list[tuple[int, int]]]:
    """Per period slot, the (frame, input) messages sent in it: each frame in `order`, the right camera's
    messages `skew` frames late, and with `burst` > 1 only every burst-th slot sends (the frames since)."""
    if args.bare:
        return [[(frame, 0), (frame, 1)] for frame in range(count)]
    slots: list[list[tuple[int, int]]] = [[] for _ in range(count + args.skew)]
    for frame in range(count):
        for index in (int(k) for k in args.order):
            slots[frame + (args.skew if index >= 2 else 0)].append((frame, index))
    if args.burst > 1:
        for slot in range(len(slots)):
            if slot % args.burst != args.burst - 1 and slot + 1 < len(slots):
                slots[slot + 1][:0] = slots[slot]
                slots[slot] = []
    return slots


def bare_messages(header: Any, width: int, height: int) -> list[Any]:
    """A DisparityImage and a PointCloud2 of the sizes stereo_node publishes (float32 disparity, 32 B/pt)."""
    from sensor_msgs.msg import PointCloud2
    from stereo_msgs.msg import DisparityImage

    disparity = DisparityImage(header=header)
    disparity.image.height, disparity.image.width, disparity.image.step = height, width, 4 * width
    disparity.image.encoding = "32FC1"
    disparity.image.data = bytes(4 * width * height)
    cloud = PointCloud2(header=header, height=height, width=width, point_step=32, row_step=32 * width)
    cloud.data = bytes(32 * width * height)
    return [disparity, cloud]


# ------------------------------------------------------------------------------------------ monitor


def run_monitor(args: argparse.Namespace) -> None:
    """Log (topic, stamp, reception time) for every message; write them as JSON on SIGINT."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image, PointCloud2
    from stereo_msgs.msg import DisparityImage

    rclpy.init()
    node = rclpy.create_node("e2e_monitor")
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    records: dict[str, list[tuple[int, int]]] = {"in": [], "disparity": [], "points2": []}
    diagnostics: dict[str, str] = {}

    def logger(topic: str) -> Any:
        log = records[topic]

        def receive(data: bytes, info: Any) -> None:
            # CDR: 4-byte encapsulation header, then std_msgs/Header's stamp (int32 sec, uint32 nanosec)
            sec = int.from_bytes(data[4:8], "little", signed=True)
            nanosec = int.from_bytes(data[8:12], "little")
            log.append((sec * 1_000_000_000 + nanosec, int(info["received_timestamp"])))

        return receive

    def keep_diagnostics(msg: Any) -> None:
        diagnostics.update({kv.key: kv.value for status in msg.status for kv in status.values})

    subscribed = [("left/image_raw", Image, "in"), ("disparity", DisparityImage, "disparity")]
    if args.points:
        subscribed.append(("points2", PointCloud2, "points2"))
    subscriptions = [
        node.create_subscription(t, f"{NAMESPACE}/{name}", logger(key), qos, raw=True) for name, t, key in subscribed
    ]
    subscriptions.append(node.create_subscription(DiagnosticArray, f"{NAMESPACE}/diagnostics", keep_diagnostics, 10))
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        usage = os.times()
        Path(args.out).write_text(
            json.dumps({"records": records, "diagnostics": diagnostics, "cpu_s": usage.user + usage.system})
        )
        node.destroy_node()
        rclpy.try_shutdown()


# ------------------------------------------------------------------------------------------ orchestrator


def proc_cpu_s(pid: int) -> float | None:
    """utime + stime of pid (all its threads), None once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / TICK


def machine_ticks() -> tuple[int, int, int]:
    """All, idle (with I/O wait) and stolen CPU ticks of the machine so far: a VM's stolen time is what the
    host gave other guests while this one had work, a run's figures move with it."""
    values = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return sum(values), values[3] + values[4], values[7]


def start(cmd: list[str], env: dict[str, str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as out:
        return subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)


def stop(process: subprocess.Popen[bytes] | None, timeout: float = 10.0) -> None:
    """SIGINT to the process we started (its own session), then SIGKILL if it does not end."""
    if process is None or process.poll() is not None:
        return
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def output_stats(
    records: list[tuple[int, int]], t_in: dict[int, int], frames: int, sent: dict[int, int]
) -> dict[str, Any]:
    """Rate and drops of one output; latency from the monitor's receipt of the input (`lat_*`) and from
    the publisher's send time of the frame's last message (`send_lat_*`; one clock, one machine)."""
    measured = [(s, t) for s, t in records if s in t_in]
    out: dict[str, Any] = {"received": len(measured), "dropped": frames - len({s for s, _ in measured})}
    times = sorted(t for _, t in measured)
    span = (times[-1] - times[0]) / 1e9 if len(times) > 1 else 0.0
    out["hz"] = (len(times) - 1) / span if span > 0 else 0.0
    latency = sorted((t - t_in[s]) / 1e6 for s, t in measured)
    if latency:
        out["lat_median"] = statistics.median(latency)
        out["lat_p95"] = latency[round(0.95 * (len(latency) - 1))]
        out["lat_max"] = latency[-1]
    from_send = sorted((t - sent[s]) / 1e6 for s, t in measured if s in sent)
    if from_send:
        out["send_lat_median"] = statistics.median(from_send)
        out["send_lat_p95"] = from_send[round(0.95 * (len(from_send) - 1))]
    return out


def run_case(case: Case, args: argparse.Namespace, workdir: Path, profile: bool) -> dict[str, Any]:
    """One run; `profile`: all three processes export config/fastdds_large_images.xml, else none does."""
    env = ros_env(args.domain_id, profile)
    label = f"{case.name}{'+profile' if profile else ''}"
    me = [sys.executable, str(Path(__file__).resolve())]
    monitor_out, sent_out = workdir / f"{label}.monitor.json", workdir / f"{label}.sent.json"
    timeline_out = workdir / f"{label}.timeline.json"
    if args.timeline:  # bench/lib/timeline_node.py in stereo_node's place
        env.update(PYTHONPATH=os.pathsep.join([str(BENCH), env.get("PYTHONPATH", "")]).rstrip(os.pathsep))
        env["STEREO_DEPTH_TIMELINE"] = str(timeline_out)
    module = "lib.timeline_node" if args.timeline else args.node_module
    node_cmd = [sys.executable, "-m", module, "--ros-args", "-r", f"__ns:={NAMESPACE}"]
    for param in (*case.params, *args.param):
        node_cmd += ["-p", param]
    node = None if case.bare else start(node_cmd, env, workdir / f"{label}.node.log")
    monitor = publisher = None
    samples: list[tuple[float, float | None, int, int, int]] = []

    def sample() -> None:
        samples.append((time.time(), proc_cpu_s(node.pid) if node else None, *machine_ticks()))

    publish_cmd = [*me, "publish", "--width", str(case.width), "--height", str(case.height)]
    publish_cmd += ["--rate", str(case.rate_hz), "--frames", str(args.frames), "--order", case.order]
    publish_cmd += ["--skew", str(case.skew), "--burst", str(case.burst), "--sent", str(sent_out)]
    publish_cmd += (["--color"] if case.color else []) + (["--bare"] if case.bare else [])
    try:
        monitor_cmd = [*me, "monitor", "--out", str(monitor_out)] + ([] if case.points else ["--no-points"])
        monitor = start(monitor_cmd, env, workdir / f"{label}.monitor.log")
        publisher = start(publish_cmd, env, workdir / f"{label}.publisher.log")
        while publisher.poll() is None:
            if node is not None and node.poll() is not None:
                sys.exit(f"stereo_node exited, see {workdir / f'{label}.node.log'}")
            sample()
            time.sleep(0.1)
        last = None
        for _ in range(50):  # drain: until the node's CPU time stops moving (at most 10 s)
            time.sleep(0.2)
            sample()
            if samples[-1][1] == last:
                break
            last = samples[-1][1]
    finally:
        stop(publisher)
        stop(monitor)
        stop(node)
    sent = {int(s): t for s, t in json.loads(sent_out.read_text()).items()}
    monitor_records = json.loads(monitor_out.read_text())
    row = summarize(case, args.frames, monitor_records, samples, sent)
    row["profile"] = "all" if profile else "none"
    if args.timeline:
        row["timeline_ms"] = timeline_breakdown(json.loads(timeline_out.read_text()), monitor_records["records"])
    return row


TIMELINE_STEPS = (
    "monitor's left image -> node's first input in DDS",
    "node's first input -> its last input in DDS",
    "last input: DDS -> its callback",
    "its callback (and any still running)",
    "callbacks -> worker",
    "worker -> publish disparity",
    "publish disparity",
    "published -> monitor",
    "monitor's left image -> monitor's disparity",
)


# A frame whose inputs reach the node more than this far apart had one repaired by DDS: a publisher on Fast DDS
# defaults (512 KB segment) overwrites an image some reader has not taken and resends it after its writer's
# 5 ms nack response delay (`--pairing` shows it); the monitor's left image likewise.
REPAIRED_MS = 3.0
MIN_FRAMES_PER_GROUP = 10
REPAIRED_STEPS = (
    "node's inputs: frames with one repaired (%)",
    "monitor's left image: frames repaired (%)",
    "  disparity, frames the node got repaired",
    "  disparity, the other frames",
)


def timeline_breakdown(
    events: dict[str, dict[str, int]], records: dict[str, list[tuple[int, int]]]
) -> dict[str, float]:
    """Medians (ms) of each step of a disparity's way, over the frames whose disparity the monitor got:
    the node's events (bench/lib/timeline_node.py) and the monitor's receipts share the system clock."""
    left, disparity = dict(records["in"]), dict(records["disparity"])  # (stamp, receipt) pairs
    steps: dict[str, list[float]] = {step: [] for step in TIMELINE_STEPS}
    for key, event in events.items():
        stamp = int(key)
        inputs = [i for i in range(4) if {f"dds {i}", f"callback {i}", f"callback end {i}"} <= event.keys()]
        seen = stamp in disparity and stamp in left and "published disparity" in event
        if stamp < FIRST_STAMP_NS or not seen or not inputs:  # warm-up frames, or a frame dropped on the way
            continue
        last = max(inputs, key=lambda i: event[f"dds {i}"])
        times = (
            left[stamp],
            min(event[f"dds {i}"] for i in inputs),
            event[f"dds {last}"],
            event[f"callback {last}"],
            max(event[f"callback end {i}"] for i in inputs),
            event["worker"],
            event["publish disparity"],
            event["published disparity"],
            disparity[stamp],
        )
        for step, (start, end) in zip(TIMELINE_STEPS[:-1], itertools.pairwise(times), strict=True):
            steps[step].append((end - start) / 1e6)
        steps[TIMELINE_STEPS[-1]].append((disparity[stamp] - left[stamp]) / 1e6)
    out = {step: statistics.median(values) for step, values in steps.items() if values}
    spread, monitor_late = steps[TIMELINE_STEPS[1]], steps[TIMELINE_STEPS[0]]
    totals = steps[TIMELINE_STEPS[-1]]
    repaired = [total for gap, total in zip(spread, totals, strict=True) if gap > REPAIRED_MS]
    whole = [total for gap, total in zip(spread, totals, strict=True) if gap <= REPAIRED_MS]
    if totals:
        out[REPAIRED_STEPS[0]] = 100.0 * len(repaired) / len(totals)
        out[REPAIRED_STEPS[1]] = 100.0 * sum(late < -REPAIRED_MS for late in monitor_late) / len(totals)
    if min(len(repaired), len(whole)) >= MIN_FRAMES_PER_GROUP:  # a median of a few frames says little
        out[REPAIRED_STEPS[2]] = statistics.median(repaired)
        out[REPAIRED_STEPS[3]] = statistics.median(whole)
    return out


def summarize(
    case: Case, frames: int, monitor: dict[str, Any], samples: list[Any], sent: dict[int, int]
) -> dict[str, Any]:
    records = {k: [tuple(r) for r in v] for k, v in monitor["records"].items()}
    sent = {s: t for s, t in sent.items() if s >= FIRST_STAMP_NS}
    t_in = sent if case.bare else {s: t for s, t in records["in"] if s >= FIRST_STAMP_NS}
    row: dict[str, Any] = {"case": case.name, "frames": frames, "inputs_seen": len(t_in)}
    row["disparity"] = output_stats(records["disparity"], t_in, frames, sent)
    row["points2"] = output_stats(records["points2"], t_in, frames, sent) if case.points else None
    outputs = [t for key in ("disparity", "points2") for s, t in records[key] if s in t_in]
    if not t_in or not outputs:
        sys.exit(f"{case.name}: {len(t_in)} inputs and {len(outputs)} outputs seen; see the logs (--logdir)")
    t0, t1 = min(t_in.values()) / 1e9, max(outputs) / 1e9
    before = [s for s in samples if s[0] <= t0] or samples[:1]
    after = [s for s in samples if s[0] >= t1] or samples[-1:]
    s0, s1 = before[-1], after[0]
    active = s1[0] - s0[0]
    node_cpu_s = s1[1] - s0[1] if s0[1] is not None and s1[1] is not None else float("nan")
    row["node_cpu_pct"] = 100.0 * node_cpu_s / active if active > 0 else float("nan")
    row["node_cpu_ms_per_frame"] = 1000.0 * node_cpu_s / max(1, row["disparity"]["received"])
    row["machine_busy_cores"] = (1.0 - (s1[3] - s0[3]) / max(1, s1[2] - s0[2])) * (os.cpu_count() or 1)
    row["machine_steal_pct"] = 100.0 * (s1[4] - s0[4]) / max(1, s1[2] - s0[2])
    diagnostics = monitor["diagnostics"]
    row["node_dropped_diag"] = diagnostics.get("dropped frames", "-")
    row["node_stage_ms"] = {
        k[: -len(" time (ms)")]: float(v) for k, v in diagnostics.items() if k.endswith(" time (ms)")
    }
    row["node_inputs"] = {k: v for k, v in diagnostics.items() if "camera_info" in k and ("lost" in k or "used" in k)}
    row["bottleneck"] = diagnostics.get("bottleneck", "-")
    row["images_in_dds_ms"] = {  # median / max: a max of 5-10 ms are images DDS lost and repaired
        k.split()[0].split("/")[-2]: v for k, v in diagnostics.items() if "image_raw time in DDS" in k
    }
    row["monitor_cpu_s"] = monitor["cpu_s"]
    return row


def median_row(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Median of every figure over the repeats of one case (like the anchor's summarize.py)."""

    def med(values: list[Any]) -> Any:
        numbers = [v for v in values if isinstance(v, (int, float)) and v == v]
        return statistics.median(numbers) if numbers else values[0]

    def merge(dicts: list[dict[str, Any]]) -> dict[str, Any]:
        """Per key, over the runs that have it (a counter the node reported in one run only)."""
        keys = dict.fromkeys(k for d in dicts for k in d)
        values = {k: [d[k] for d in dicts if k in d] for k in keys}
        return {k: merge(v) if isinstance(v[0], dict) else med(v) for k, v in values.items()}

    merged = merge([{k: v for k, v in r.items() if v is not None} for r in rows])
    merged["points2"] = merged.get("points2")
    merged["case"], merged["runs"] = rows[0]["case"], len(rows)
    return merged


def latency_text(output: dict[str, Any] | None) -> str:
    if not output or "send_lat_median" not in output:
        return "-"
    from_input = f"{output['lat_median']:.0f}" if "lat_median" in output else "-"
    return f"{output['send_lat_median']:.0f} / {output['send_lat_p95']:.0f} / {from_input}"


def print_header() -> None:
    print(
        f"{'case':26s}{'profile':>8s}{'disp Hz':>8s}{'pts Hz':>8s}{'dropped':>9s}{'diag':>6s}"
        f"{'disp lat ms':>17s}{'pts lat ms':>17s}{'node CPU':>9s}{'ms/frame':>9s}{'machine':>8s}{'stolen':>7s}"
    )


def print_row(r: dict[str, Any]) -> None:
    """dropped: replayed frames without a disparity / without a points2; diag: the node's own count;
    lat: median / p95 from the publisher's send time, median from the monitor's receipt of the input."""
    d, p = r["disparity"], r["points2"]
    points_hz = f"{p['hz']:.1f}" if p else "-"
    dropped = f"{d['dropped']:.0f}" + (f"/{p['dropped']:.0f}" if p else "")
    print(
        f"{r['case']:26s}{r['profile']:>8s}{d['hz']:8.1f}{points_hz:>8s}{dropped:>9s}{r['node_dropped_diag']!s:>6s}"
        f"{latency_text(d):>17s}{latency_text(p):>17s}{r['node_cpu_pct']:8.0f}%{r['node_cpu_ms_per_frame']:9.1f}"
        f"{r['machine_busy_cores']:8.2f}{r['machine_steal_pct']:6.0f}%",
        flush=True,
    )


def print_anchor_comparison(rows: list[dict[str, Any]], anchor: dict[str, Any]) -> None:
    """Side by side with the anchor (its summary.json, or its runs interleaved with ours): each anchor
    case, then our runs of it per profile (32 B points: ROS 2's layout; 16 B: ROS 1's, the bytes the
    anchor publishes). dropped: frames without a disparity / without a points2."""
    print(
        f"\n{'case (anchor name)':26s}{'':28s}{'disp Hz':>8s}{'pts Hz':>8s}{'dropped':>10s}"
        f"{'disp lat ms':>12s}{'pts lat ms':>11s}{'CPU %':>7s}"
    )
    for name in dict.fromkeys(ANCHOR_NAMES[r["case"]] for r in rows if r["case"] in ANCHOR_NAMES):
        a = anchor.get(name)
        if a is None:
            continue
        a_pts = f"{a['points2_hz']:.1f}" if a.get("points2_hz") else "-"
        a_pl = f"{a['points2_lat_ms_median']:.1f}" if a.get("points2_lat_ms_median") else "-"
        a_drop = f"{a['disparity_dropped']:.0f}" + (f"/{a['points2_dropped']:.0f}" if a.get("points2_hz") else "")
        print(
            f"{name:26s}{'C++ ROS 1 (16 B/pt)':28s}{a['disparity_hz']:8.1f}{a_pts:>8s}{a_drop:>10s}"
            f"{a['disparity_lat_ms_median']:12.1f}{a_pl:>11s}{a['node_cpu_pct']:7.0f}"
        )
        for r in rows:
            if ANCHOR_NAMES.get(r["case"]) != name:
                continue
            d, p = r["disparity"], r["points2"] or {}
            label = "ours" + ("" if not r["points2"] else " 16 B/pt" if "16b" in r["case"] else " 32 B/pt")
            label += f", profile {r['profile']}"
            pts = f"{p['hz']:.1f}" if p else "-"
            pl = f"{p['lat_median']:.1f}" if p.get("lat_median") else "-"
            drop = f"{d['dropped']:.0f}" + (f"/{p['dropped']:.0f}" if p else "")
            print(
                f"{'':26s}{label:28s}{d['hz']:8.1f}{pts:>8s}{drop:>10s}"
                f"{d['lat_median']:12.1f}{pl:>11s}{r['node_cpu_pct']:7.0f}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="role")
    pub = sub.add_parser("publish")
    pub.add_argument("--width", type=int, default=640)
    pub.add_argument("--height", type=int, default=480)
    pub.add_argument("--rate", type=float, default=30.0)
    pub.add_argument("--frames", type=int, default=300)
    pub.add_argument("--order", default="0123")
    pub.add_argument("--skew", type=int, default=0)
    pub.add_argument("--burst", type=int, default=1)
    pub.add_argument("--color", action="store_true")
    pub.add_argument("--bare", action="store_true")
    pub.add_argument("--sent", required=True)
    mon = sub.add_parser("monitor")
    mon.add_argument("--out", required=True)
    mon.add_argument("--no-points", dest="points", action="store_false")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    parser.add_argument("--repeats", type=int, default=1, help="runs per case; the table shows medians")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--param", action="append", default=[], metavar="NAME:=VALUE", help="extra stereo_node -p")
    parser.add_argument("--node-module", default="stereo_depth.nodes.stereo_node", help="python -m MODULE")
    parser.add_argument("--domain-id", help="default: ROS_DOMAIN_ID, else a free one (bench/lib/domain_lock.py)")
    parser.add_argument(
        "--profiles",
        nargs="+",
        choices=("none", "all"),
        default=["all"],
        help="none: no process exports a profile (stereo_node loads its own); all: all three export it",
    )
    parser.add_argument(
        "--pairing", action="store_true", help="the input-pairing cases (orders, skew, bursts, bare rclpy), both ways"
    )
    parser.add_argument(
        "--anchor",
        type=Path,
        metavar="DIR",
        help="the C++ anchor's folder (its run.sh): run it after each of our runs of a case it has, and print "
        "both side by side",
    )
    parser.add_argument("--anchor-work", type=Path, default=Path("/tmp/sip_anchor"), help="the anchor's WORK folder")
    parser.add_argument(
        "--timeline",
        action="store_true",
        help="run bench/lib/timeline_node.py in stereo_node's place and print where the disparity's latency goes",
    )
    parser.add_argument("--json", type=Path, help="write every run's figures here")
    parser.add_argument("--logdir", type=Path, help="keep the processes' logs here (default: a temporary folder)")
    args = parser.parse_args()
    print_machine()
    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = args.domain_id
    args.domain_id = isolate_on_this_host()
    if args.role == "publish":
        run_publisher(args)
        return
    if args.role == "monitor":
        run_monitor(args)
        return
    if args.pairing:
        args.cases, args.profiles = PAIRING, ["none", "all"]
    if args.anchor is not None and not (args.anchor / "run.sh").is_file():
        parser.error(f"--anchor {args.anchor}: no run.sh there (the ROS 1 stereo_image_proc anchor's folder)")
    load = Path("/proc/loadavg").read_text().split()[:3]
    print(machine_line(), flush=True)
    print(
        f"stereo_node end to end over DDS: {args.frames} frames per case, {os.cpu_count()} cores, "
        f"load before {' '.join(load)}, ROS_DOMAIN_ID {args.domain_id}, "
        f"profiles: {' and '.join(args.profiles)}",
        flush=True,
    )
    # numba's kernels compiled (or loaded) now: a census node compiles them before it subscribes, on a fresh
    # machine 23-37 s here and about twice that on a machine half as fast, near the publisher's 60 s wait
    subprocess.run([sys.executable, "-m", "stereo_depth.cli", "compile"], check=True, stdout=subprocess.DEVNULL)
    all_runs: list[dict[str, Any]] = []
    runs: dict[tuple[str, str], list[dict[str, Any]]] = {(n, p): [] for p in args.profiles for n in args.cases}
    anchor_runs: dict[str, list[dict[str, Any]]] = {}
    print_header()
    with tempfile.TemporaryDirectory(prefix="e2e_dds_") as tmp:
        logdir = args.logdir or Path(tmp)
        logdir.mkdir(parents=True, exist_ok=True)
        # repeats outermost and the anchor after each case: the runs interleave, so a load that comes and
        # goes on a shared machine falls on both
        for _ in range(args.repeats):
            for name in args.cases:
                for profile in args.profiles:
                    run = run_case(CASES[name], args, logdir, profile == "all")
                    runs[(name, profile)].append(run)
                    all_runs.append(run)
                    print_row(run)
                anchor_name = ANCHOR_NAMES.get(name)
                if args.anchor is not None and anchor_name is not None:
                    figures = run_anchor(args.anchor, anchor_name, args, logdir)
                    if figures is not None:
                        anchor_runs.setdefault(anchor_name, []).append(figures)
                        print(f"{'anchor ' + anchor_name:26s}{'C++':>8s}" + anchor_text(figures), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"runs": all_runs, "anchor": anchor_runs}, indent=1))
    rows = [median_row(r) if len(r) > 1 else r[0] for r in runs.values() if r]
    if args.repeats > 1:
        print(f"\nmedians of {args.repeats} runs")
        print_header()
        for row in rows:
            print_row(row)
    print("diag: the node's own 'dropped frames', warm-up frames included (a few wait for start-up work)")
    print("machine: busy cores over the run; stolen: CPU time the VM's host gave to other guests meanwhile")
    print("\nthe node's own per-stage times (its diagnostics: mean of the last 30 frames), ms")
    for r in rows:
        print(f"{r['case']:26s}{r['profile']:>6s}  " + "  ".join(f"{k} {v:.1f}" for k, v in r["node_stage_ms"].items()))
    print("\nthe node's camera_info accounting, its images' time in DDS and its bottleneck line (diagnostics)")
    for r in rows:
        if r["node_inputs"]:
            counts = ", ".join(f"{k.split('/')[-1]} {v}" for k, v in r["node_inputs"].items())
            in_dds = ", ".join(f"{camera} {v}" for camera, v in r.get("images_in_dds_ms", {}).items())
            print(
                f"{r['case']:26s}{r['profile']:>6s}  {counts}; images in DDS ms (median / max): {in_dds or '-'}; "
                f"bottleneck: {r['bottleneck']}"
            )
    if args.timeline:
        print("\nwhere the disparity's latency goes (bench/lib/timeline_node.py; medians over the frames, ms)")
        for r in rows:
            print(f"{r['case']:26s}{r['profile']:>6s}")
            for step, value in r.get("timeline_ms", {}).items():
                print(f"  {step:48s}{value:7.{0 if step.endswith('(%)') else 2}f}")
    if args.anchor is not None:
        print_anchor_comparison(rows, {name: median_figures(f) for name, f in anchor_runs.items()})


def anchor_text(a: dict[str, Any]) -> str:
    points = f"{a['points2_hz']:.1f}" if a.get("points2_hz") else "-"
    lat = f"{a['disparity_lat_ms_median']:.0f}" + (
        f" / {a['points2_lat_ms_median']:.0f}" if a.get("points2_lat_ms_median") else ""
    )
    return f"{a['disparity_hz']:8.1f}{points:>8s}{a['disparity_dropped']:9.0f}{'':6s}  latency from input {lat} ms"


def median_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Median of each of the anchor's figures over its runs."""
    out: dict[str, Any] = {}
    for key, value in runs[0].items():
        numbers = [r[key] for r in runs if isinstance(r.get(key), (int, float))]
        out[key] = statistics.median(numbers) if numbers and isinstance(value, (int, float)) else value
    out["runs"] = len(runs)
    return out


if __name__ == "__main__":
    main()
