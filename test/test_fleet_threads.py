"""Fleet workers match on their share of the cores: `--jobs 2` on two cores runs no worker on more than
one thread, whatever OpenCV and numba would start by default (every core each).

The threads are counted from outside, as `top -H` would: each worker process's threads that spent a
real part of its CPU time. With the OpenMP layer numba uses here and OpenCV's pool, the calling thread
takes part in the work, so one working thread is what a one-thread share looks like.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stereo_depth.core.threads import available_cores

BAGS = Path(__file__).resolve().parents[1] / "bags"
BUSY_SHARE = 0.05  # a thread with at least this part of its process's CPU time did work
TICK = os.sysconf("SC_CLK_TCK")


def workers(pid: int) -> list[int]:
    """The multiprocessing workers `pid` spawned (not its resource tracker)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) == pid and b"spawn_main" in (stat.parent / "cmdline").read_bytes():
                found.append(int(stat.parent.name))
        except OSError:
            continue
    return found


def thread_cpu_s(pid: int) -> dict[int, float]:
    """utime + stime of every thread of `pid`; empty once it is gone."""
    out = {}
    for stat in Path(f"/proc/{pid}/task").glob("*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[int(stat.parent.name)] = (int(fields[11]) + int(fields[12])) / TICK
    return out


def working_threads(cpu: dict[int, float]) -> int:
    total = sum(cpu.values())
    return sum(1 for seconds in cpu.values() if total > 0 and seconds >= BUSY_SHARE * total)


@pytest.mark.skipif(available_cores() != 2, reason="the claim is about two workers on two cores")
def test_two_workers_on_two_cores_each_work_on_one_thread(tmp_path: Path) -> None:
    inputs = tmp_path / "in"
    for name in ("middlebury", "euroc_raw"):
        shutil.copytree(BAGS / name, inputs / name)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")}
    # quality: census_sgm's numba kernels and OpenCV's remap and filters, each parallel by default
    command = [
        str(Path(sys.executable).parent / "stereo-depth"),
        "process",
        str(inputs),
        "--out-dir",
        str(tmp_path / "out"),
    ]
    command += ["--jobs", "2", "--profile", "quality", "--outputs", "disparity"]
    run = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    seen: dict[int, dict[int, float]] = {}  # worker pid -> thread -> CPU seconds (last reading)
    while run.poll() is None:
        for pid in workers(run.pid):
            seen.setdefault(pid, {}).update(thread_cpu_s(pid))
        time.sleep(0.1)
    output = run.stdout.read().decode() if run.stdout else ""
    assert run.returncode == 0, output
    counts = {pid: working_threads(cpu) for pid, cpu in seen.items()}
    print(f"\nworking threads per worker (--jobs 2, 2 cores): {sorted(counts.values())}")
    assert len(counts) == 2
    assert all(count == 1 for count in counts.values()), counts
