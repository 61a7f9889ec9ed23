"""A pipeline's frames reuse the pages the frame before freed (stereo_depth/core/memory.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from stereo_depth.core.memory import keep_freed_memory

BENCH = Path(__file__).resolve().parents[1] / "bench"

# five frames of the quality profile (census_sgm) at 640x480 after three to warm up; prints their page faults
CHILD = f"""
import resource, sys
sys.path.insert(0, {str(BENCH)!r})
from pipeline_stages import load_pair
from stereo_depth.core import memory
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
if sys.argv[1] == "glibc":
    memory._kept.append(False)  # as if already done: malloc keeps glibc's own thresholds
left, right, camera = load_pair(640, 480)
pipeline = StereoPipeline(make_params("quality"))
for _ in range(3):
    pipeline.process(left, right, camera)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    pipeline.process(left, right, camera)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(variant: str) -> int:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, variant], capture_output=True, text=True, check=True, timeout=120
    )
    return int(done.stdout.split()[-1])


@pytest.mark.skipif(not keep_freed_memory(), reason="the C library has no mallopt (not glibc)")
def test_frames_after_the_first_reuse_freed_pages_instead_of_faulting_in_new_ones() -> None:
    kept, glibc = faults("kept"), faults("glibc")
    # glibc's own thresholds: the census core's buffers of each frame fault in anew
    assert glibc > 5 * 200, f"the baseline took only {glibc} page faults in 5 frames"
    assert kept * 10 < glibc, f"{kept} page faults in 5 frames with freed memory kept, {glibc} without"
