"""Fleet: frames/s of `stereo-depth process IN... --out-dir` on 4 bags with --jobs 1, --jobs 2 and --ray,
and what one Ray task costs when it does nothing.

The 4 bags are the offline bench's VGA stream (bench/offline_process.py `write_bag`: the anchor's
textured layers, uncompressed MCAP), FRAMES frames each. Each mode is the real command line in a fresh
process, timed from start to exit (worker start-up and Ray's start included), writing the disparity
only so the disk does not set the pace. OpenCV runs one thread per process (OPENCV_FOR_THREADS_NUM=1)
so the matcher is a one-core matcher and the scaling measured is the fleet's, not OpenCV's own
threads. Ray runs twice: as it comes (workers at niceness 15) and with RAY_worker_niceness=0.
"in tasks" is frames over the summed seconds inside process_bag (the per-core rate that a cluster
projection multiplies). Ray's overhead is the mean wall time of no-op tasks on a local instance.

    flock /tmp/stereo_depth_cpu.lock .venv/bin/python bench/fleet.py [--frames 150] [--profile default] [--markdown]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row, times
from offline_process import write_bag

BAGS = 4
# A local instance on loopback: no usage statistics, and no token written to ~/.ray (Ray 2.60 creates
# one for a new local instance, which later `ray start` heads on this machine would then demand).
RAY_LOOPBACK = {"RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}
# mode: (flags, extra environment). Ray starts its workers at niceness 15, so on a machine where
# anything else runs they get less CPU than the local workers; "nice 0" gives them the same priority.
MODES: dict[str, tuple[list[str], dict[str, str]]] = {
    "--jobs 1": (["--jobs", "1"], {}),
    "--jobs 2": (["--jobs", "2"], {}),
    "--ray": (["--ray"], {}),
    "--ray nice 0": (["--ray"], {"RAY_worker_niceness": "0"}),
}


def run_mode(
    bags: list[Path], out: Path, profile: str, flags: list[str], extra_env: dict[str, str]
) -> tuple[float, dict[str, float]]:
    """Wall seconds of one fleet run and its report's totals."""
    report = out.with_suffix(".json")
    command = [sys.executable, "-m", "stereo_depth.cli", "process", *map(str, bags), "--out-dir", str(out)]
    command += ["--profile", profile, "--outputs", "disparity", "--report", str(report), *flags]
    env = {**os.environ, "OPENCV_FOR_THREADS_NUM": "1", **RAY_LOOPBACK, **extra_env}
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    bags_report = json.loads(report.read_text())["bags"]
    frames = sum(b["frames_out"] for b in bags_report)
    seconds = sum(b["seconds"] for b in bags_report)
    return wall, {"frames": frames, "task_seconds": seconds}


def ray_costs(tasks: int) -> tuple[float, float]:
    """Seconds to start a local instance and have its workers up, and milliseconds per no-op task
    (submitted together, awaited) once they are."""
    import ray

    os.environ.update(RAY_LOOPBACK)
    start = time.perf_counter()
    ray.init(address="local", include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    try:
        noop = ray.remote(num_cpus=1)(lambda: None)
        ray.get([noop.remote() for _ in range(20)])
        started = time.perf_counter() - start
        start = time.perf_counter()
        ray.get([noop.remote() for _ in range(tasks)])
        return started, (time.perf_counter() - start) / tasks * 1e3
    finally:
        ray.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150, help="frames per bag")
    parser.add_argument("--profile", default="default")
    parser.add_argument("--size", default="640x480")
    args = parse_bench_arguments(parser)
    width, height = map(int, args.size.split("x"))
    print(f"{BAGS} bags x {args.frames} frames {args.size}, profile {args.profile}, {os.cpu_count()} cores")
    if args.markdown:
        columns = ("mode", "wall s", "frames/s", "vs `--jobs 1`", "frames/s per core inside the tasks")
        print(table_header(columns))
    else:
        print(f"{'mode':14s}{'wall s':>8s}{'frames/s':>10s}{'vs jobs 1':>11s}{'in tasks f/s/core':>19s}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bags = [folder / f"bag{i}" for i in range(BAGS)]
        for bag in bags:
            write_bag(bag, width, height, args.frames)
        baseline = 0.0
        walls, frame_ms = {}, 0.0  # frame_ms: one frame's work in a task, `--jobs 1`
        for name, (flags, extra_env) in MODES.items():
            out = folder / name.strip("-").replace(" ", "_")
            wall, totals = run_mode(bags, out, args.profile, flags, extra_env)
            rate = totals["frames"] / wall
            baseline = baseline or rate
            per_core = totals["frames"] / totals["task_seconds"]
            walls[name], frame_ms = wall, frame_ms or 1000.0 / per_core
            if args.markdown:
                cells = (f"`{name}`", f"{wall:.1f}", f"{rate:.1f}", times(rate / baseline), f"{per_core:.1f}")
                print(table_row(cells), flush=True)
                continue
            print(f"{name:14s}{wall:8.2f}{rate:10.1f}{rate / baseline:10.2f}x{per_core:19.1f}", flush=True)
    started, per_task = ray_costs(500)
    start_share, task_share = started / walls["--ray"], per_task / frame_ms
    print(
        f"\nRay: {started:.1f} s to start a local instance and its workers ({times(start_share)} the `--ray` run's",
        end="",
    )
    print(f" wall time); {per_task:.2f} ms per no-op task ({task_share:.3f}x one frame's work in a task)")


if __name__ == "__main__":
    main()
