"""Fleet workers match on their share of the cores: `--jobs 2` on two cores runs no worker on more than
one thread, whatever OpenCV and numba would start by default (every core each).

Two counts: what OpenCV and numba say they match with (the run's --report), and from outside, as
`top -H` would, each worker's threads that spent a real part of its CPU time (the thread calling
OpenCV or numba takes part in the work, so one working thread is what a one-thread share looks like).
On a machine busy with other work the libraries' helper threads get little CPU even when they are
started, so the reported counts are the ones that tell a limit from none.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from waiting import wait_until

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
    for copy in range(2):  # enough frames that the matching, not start-up, is most of a worker's time
        for name in ("middlebury", "euroc_raw"):
            shutil.copytree(BAGS / name, inputs / f"{name}_{copy}")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")}
    # quality: census_sgm's numba kernels and OpenCV's remap and filters, each parallel by default
    command = [
        str(Path(sys.executable).parent / "stereo-depth"),
        "process",
        str(inputs),
        "--out-dir",
        str(tmp_path / "out"),
    ]
    command += ["--jobs", "2", "--profile", "quality", "--set", "disparity_range=128", "--outputs", "disparity"]
    command += ["--report", str(tmp_path / "report.json")]
    run = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    seen: dict[int, dict[int, float]] = {}  # worker pid -> thread -> CPU seconds (last reading)

    def ended() -> bool:
        for pid in workers(run.pid):
            seen.setdefault(pid, {}).update(thread_cpu_s(pid))
        return run.poll() is not None

    try:
        wait_until(ended, "the fleet run to end", 300.0, 0.1)
    finally:
        run.kill()  # no-op once it ended
    output = run.stdout.read().decode() if run.stdout else ""
    assert run.returncode == 0, output
    reported = [bag["threads"] for bag in json.loads((tmp_path / "report.json").read_text())["bags"]]
    counts = {pid: working_threads(cpu) for pid, cpu in seen.items()}
    print(f"\n--jobs 2 on 2 cores: threads per bag {reported}; working threads per worker {sorted(counts.values())}")
    assert len(reported) == 4 and all(t == {"opencv": 1, "numba": 1} for t in reported), reported
    assert len(counts) == 2 and all(count == 1 for count in counts.values()), counts
