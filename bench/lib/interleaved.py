"""Benches that compare processes frame by frame (bench/simd_match_ratio.py, bench/bm_kernels.py).

Each child process keeps its matchers loaded and serves one frame per line it reads; the parent asks
each child in turn, `--repeat` times, so a load change on the machine hits every child alike.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from typing import Any

# before each timed call: the thread pools of the call before (OpenCV's, numba's TBB) stop spinning
IDLE_S = 0.05


def serve(frame: Callable[[], Any], ready: Any) -> None:
    """The child's side: three frames to warm up (compile or load the kernels, reach the steady state),
    then `ready` as a JSON line, then one frame's figures as a JSON line per line read."""
    for _ in range(3):
        frame()
    print(json.dumps(ready), flush=True)
    for _ in sys.stdin:
        print(json.dumps(frame()), flush=True)


def start(arguments: list[str], env: dict[str, str]) -> subprocess.Popen[str]:
    """A child: this Python running `arguments` with `env`, talking over its stdin and stdout."""
    command = [sys.executable, *arguments]
    return subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)


def frames_in_turn(
    children: dict[str, subprocess.Popen[str]], repeat: int
) -> tuple[dict[str, Any], dict[str, list[Any]]]:
    """Each child's `ready` line, then `repeat` rounds of one frame from each child in turn; the children
    are closed afterwards."""
    ready = {}
    for name, process in children.items():
        assert process.stdout is not None
        ready[name] = json.loads(process.stdout.readline())
        print(f"{name}: ready", file=sys.stderr, flush=True)
    runs: dict[str, list[Any]] = {name: [] for name in children}
    for _ in range(repeat):
        for name, process in children.items():
            assert process.stdin is not None and process.stdout is not None
            process.stdin.write("frame\n")
            process.stdin.flush()
            runs[name].append(json.loads(process.stdout.readline()))
    for process in children.values():
        assert process.stdin is not None
        process.stdin.close()
        process.wait()
    return ready, runs
