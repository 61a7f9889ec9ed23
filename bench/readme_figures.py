"""`make bench-readme`: every speed figure README.md quotes, remeasured in one run, in the README's layout.

Runs each bench the README quotes, with the README's arguments, one after another while holding the CPU
lock (/tmp/stereo_depth_cpu.lock, as `flock` takes it: no other bench shares the cores meanwhile). It
prints the machine once, then section by section (README headings) a "Measured on:" line and the
benches' markdown tables, ready to paste over the old ones. Every table carries a ratio against a
baseline measured in the same run: ratios carry over to other machines better than times. The
benches' own progress goes to stderr, the tables to stdout.

--quick runs everything with fewer repeats and frames, to check that it works (its figures are noise).
--simd measures another SIMD level on this machine: numba compiles for that CPU (with a cache folder
of its own) and OpenCV's dispatcher leaves out the wider levels (OPENCV_CPU_DISABLE).

    make bench-readme [ARGS="--quick --simd avx2"]
    .venv/bin/python bench/readme_figures.py [--quick] [--simd native|avx2|128] [--sections NAME ...]
        [--data ../shared/data] [--out out/bench-readme]
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import readme_e2e
from markdown_table import table_header, table_row, times

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
CPU_LOCK = Path("/tmp/stereo_depth_cpu.lock")
# --simd: the environment that makes numba and OpenCV use that level on a wider machine
SIMD_ENV = {
    "native": {},
    "avx2": {"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": "", "OPENCV_CPU_DISABLE": "AVX512-SKX"},
    "128": {
        "NUMBA_CPU_NAME": "x86-64-v2",
        "NUMBA_CPU_FEATURES": "",
        "OPENCV_CPU_DISABLE": "AVX,AVX2,AVX512-SKX,FP16",
    },
}


def simd_env(level: str) -> dict[str, str]:
    """SIMD_ENV of that level, with a numba cache folder of its own (~/.cache/stereo_depth/numba_<level>)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "stereo_depth" / f"numba_{level}"
    return {**SIMD_ENV[level], "NUMBA_CACHE_DIR": str(cache)}


@dataclass(frozen=True)
class Run:
    """What each section needs: the command line's options and a scratch folder for the benches' reports."""

    args: argparse.Namespace
    work: Path

    def bench(self, script: str, *arguments: str, quick: tuple[str, ...] = ()) -> bool:
        """A bench with the README's arguments (--quick: with `quick` added) and --markdown; its
        output without its machine header (printed once, above everything)."""
        command = [sys.executable, str(BENCH / script), *arguments, *(quick if self.args.quick else ()), "--markdown"]
        return forward_markdown(command)

    def command(self, *arguments: str) -> bool:
        """A command whose output is progress, not figures (stderr)."""
        print(f"$ {' '.join(arguments)}", file=sys.stderr, flush=True)
        return subprocess.run(arguments, stdout=sys.stderr, check=False).returncode == 0


def forward_markdown(command: list[str]) -> bool:
    """Runs a bench and prints its output but its leading machine header; False (and a note) if it failed."""
    print(f"$ {' '.join(command)}", file=sys.stderr, flush=True)
    with subprocess.Popen(command, stdout=subprocess.PIPE, text=True) as child:
        assert child.stdout is not None
        header = True
        for line in child.stdout:
            if header and (line.startswith("# ") or not line.strip()):
                continue  # the bench's machine header: the same machine as ours
            header = False
            print(line, end="", flush=True)
    if child.returncode != 0:
        print(f"(failed: exit {child.returncode}; see the output above on stderr)")
    return child.returncode == 0


def scenes(run: Run) -> list[str]:
    """The README's evaluation scenes: Middlebury 2001-2014 and KITTI with ground truth (--quick: 4)."""
    found = sorted(str(p) for p in run.args.data.glob("*/*/") if p.parent.name.startswith(("middlebury", "kitti")))
    return found[:4] if run.args.quick else found


def parameters(run: Run) -> bool:
    print("What the left-right check keeps (`bench/left_right_check.py`):\n")
    scenes = ("test/data/scenes/artl", "test/data/scenes/cones", "test/data/scenes/tsukuba")
    return run.bench("left_right_check.py", *scenes)


def depth_for_navigation(run: Run) -> bool:
    print("What a cloud costs per VGA-sized frame (752x480 EuRoC, `bench/cloud_outputs.py`):\n")
    ok = run.bench("cloud_outputs.py", quick=("--repeat", "2"))
    print("\nWhat depth/compressedDepth costs per 752x480 EuRoC depth frame (`bench/compressed_depth.py`):\n")
    ok = run.bench("compressed_depth.py", quick=("--repeat", "2")) and ok
    print("\nThe temporal filter over time (`bench/temporal.py`):\n")
    bundled = [f"test/data/scenes/{name}" for name in ("artl", "cones", "tsukuba")]
    more = [
        str(run.args.data / name) for name in ("middlebury2006/aloe", "middlebury2006/baby1", "middlebury2003/teddy")
    ]
    found = [*bundled, *(path for path in more if Path(path).is_dir())]
    return run.bench("temporal.py", "--scenes", *found, quick=("--frames", "12", "--warm-up", "4")) and ok


def inputs_and_outputs_over_dds(run: Run) -> bool:
    return readme_e2e.pairing(run.work, run.args.quick)


def recorded_bags(run: Run) -> bool:
    print("What compressed input costs (`bench/compressed_input.py`):\n")
    return run.bench("compressed_input.py", quick=("--repeat", "2"))


def many_bags(run: Run) -> bool:
    print("How far it scales (`bench/fleet.py`):\n")
    return run.bench("fleet.py", quick=("--frames", "20"))


def profiles_and_accuracy(run: Run) -> bool:
    found = scenes(run)
    ok = True
    if found:
        ok = eval_profiles(run, found) and ok
        print(f"\nConfidence (`bench/confidence.py`, profile quality, {len(found)} scenes):\n")
        ok = run.bench("confidence.py", *found) and ok
    else:
        print(f"(profile table and confidence skipped: no scenes under {run.args.data}; pass --data)")
    print("\nOne comparison on Middlebury Cones (`bench/compare_profiles.py`):\n")
    picture = run.args.out / "profiles_cones.png"
    cones = ("test/data/scenes/cones", "--out", str(picture))
    ok = run.bench("compare_profiles.py", *cones, quick=("--repeat", "1")) and ok
    print("\nThe census core's matching against OpenCV's SGBM 3-way, 128 disparities (`bench/pipeline_stages.py`):\n")
    arguments = ("--profiles", "default", "quality", "--disparity-range", "128")
    ok = run.bench("pipeline_stages.py", *arguments, quick=("--repeat", "2")) and ok
    print("\nThe match beside a thread running Python, by the GIL's hand-over interval (`bench/gil_handover.py`):\n")
    ok = run.bench("gil_handover.py", quick=("--repeat", "2")) and ok
    print()
    return readme_e2e.quality(run.work, run.args.quick) and ok


# (label in the README, eval options): the rows of the profile table, `default` first (the baseline)
EVAL_PROFILES = (
    ("`default` (recommended)", ("--profile", "default")),
    ("`fast`", ("--profile", "fast")),
    ("`quality`", ("--profile", "quality")),
    ("`quality` + `fill_holes:=true`", ("--profile", "quality", "--set", "fill_holes=true")),
    ("`stereo_image_proc`", ("--profile", "stereo_image_proc")),
)


def eval_profiles(run: Run, found: list[str]) -> bool:
    """`stereo-depth eval` per profile (best of 3 per scene), the means as the README's profile table."""
    repeat = "1" if run.args.quick else "3"
    means: dict[str, dict[str, float]] = {}
    for label, options in EVAL_PROFILES:
        report = run.work / f"eval_{len(means)}.json"
        command = [sys.executable, "-m", "stereo_depth.cli", "eval", *found, *options, "--repeat", repeat]
        if not run.command(*command, "--json", str(report)):
            print(f"(failed: {' '.join(options)})")
            return False
        means[label] = json.loads(report.read_text())["mean"]
    data = os.path.relpath(run.args.data, ROOT)
    print(f"{len(found)} scenes with ground truth under {data}, times the best of {repeat} runs per scene:\n")
    columns = ("profile", "mean bad-2", "bad-2 over estimated", "density", "ms per scene", "vs `default`")
    print(table_header(columns))
    baseline = means[EVAL_PROFILES[0][0]]["ms"]
    for label, mean in means.items():
        cells = (label, f"{mean['bad2']:.3f}", f"{mean['bad2_est']:.3f}", f"{mean['density']:.3f}", f"{mean['ms']:.1f}")
        print(table_row((*cells, times(mean["ms"] / baseline))))
    return True


def performance(run: Run) -> bool:
    ok = readme_e2e.anchor(run.work, run.args.quick)
    print("\nHow the matchers use two cores (`bench/parallel_matching.py`):\n")
    ok = run.bench("parallel_matching.py", quick=("--frames", "2")) and ok
    print("\nOur BM kernels against OpenCV's StereoBM at three SIMD levels, interleaved (`bench/bm_kernels.py`):\n")
    ok = run.bench("bm_kernels.py", quick=("--repeat", "2")) and ok
    print("\nPer frame, the node's own work against the bare OpenCV calls (`bench/pipeline_stages.py`):\n")
    ok = run.bench("pipeline_stages.py", quick=("--repeat", "2")) and ok
    print("\nThe census core against SGBM 3-way at three SIMD levels, interleaved (`bench/simd_match_ratio.py`):\n")
    ok = run.bench("simd_match_ratio.py", quick=("--repeat", "2")) and ok
    print("\nWhere the census core's time goes, step by step (`bench/census_steps.py`):\n")
    ok = run.bench("census_steps.py", quick=("--repeat", "2")) and ok
    print("\nInside the census core's fused kernel, by kind of work (`bench/kernel_profile.py`):\n")
    if shutil.which("perf") and shutil.which("objdump"):
        ok = run.bench("kernel_profile.py", quick=("--frames", "2")) and ok
    else:
        print("(skipped: needs Linux perf and objdump)")
    print("\nBM after the cores sat idle (`bench/idle_gap.py`):\n")
    ok = run.bench("idle_gap.py", quick=("--frames", "10", "--rounds", "1")) and ok
    print("\nWhat one wake of rclpy's executor costs the node (`bench/executor_wake.py`):\n")
    ok = run.bench("executor_wake.py", quick=("--batches", "2")) and ok
    print("\nPublishing points2 while the next frame is matched (`bench/serialized_publish.py`):\n")
    ok = run.bench("serialized_publish.py", quick=("--frames", "5")) and ok
    print("\nPage faults and time per frame, freed memory kept or not (`bench/page_faults.py`):\n")
    ok = run.bench("page_faults.py", quick=("--repeat", "2")) and ok
    print("\nOffline, `stereo-depth process` against a bare loop (`bench/offline_process.py`):\n")
    arguments = ("--profiles", "stereo_image_proc", "--sizes", "640x480", "--frames", "100")
    return run.bench("offline_process.py", *arguments, quick=("--frames", "20", "--repeats", "1")) and ok


# README heading -> what prints its figures, in the README's order
SECTIONS: dict[str, Callable[[Run], bool]] = {
    "Parameters": parameters,
    "Depth for navigation and mapping": depth_for_navigation,
    "Inputs and outputs over DDS": inputs_and_outputs_over_dds,
    "Recorded bags": recorded_bags,
    "Many bags, long bags, a Ray cluster": many_bags,
    "Profiles and accuracy": profiles_and_accuracy,
    "Performance": performance,
}

# those that run the census_sgm core (or numba kernels beside it)
CENSUS_SECTIONS = {"Parameters", "Depth for navigation and mapping", "Profiles and accuracy", "Performance"}


def machine_header() -> tuple[str, str]:
    """The machine header and the 'Measured on:' line as the benches see the machine: from a fresh process
    with this run's environment (numba and OpenCV read their SIMD settings when they are imported)."""
    code = "from stereo_depth.machine import measured_on, print_machine; print_machine(); print(measured_on())"
    printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    header, measured_on = printed.strip().rsplit("\n", 1)
    return header.strip(), measured_on


def hold_cpu_lock() -> int:
    """The lock `flock /tmp/stereo_depth_cpu.lock` takes, held until this process ends."""
    handle = os.open(CPU_LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        print(f"waiting for {CPU_LOCK} (another bench holds it)", file=sys.stderr, flush=True)
        fcntl.flock(handle, fcntl.LOCK_EX)
    return handle


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats and frames: checks that it works")
    parser.add_argument("--simd", choices=sorted(SIMD_ENV), default="native", help="the SIMD level to measure")
    parser.add_argument("--sections", nargs="+", choices=list(SECTIONS), default=list(SECTIONS), metavar="HEADING")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data", help="the profile table's scenes")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench-readme", help="pictures")
    args = parser.parse_args()
    if args.simd != "native":  # for every bench this run starts
        os.environ.update(simd_env(args.simd))
    lock = hold_cpu_lock()
    args.out.mkdir(parents=True, exist_ok=True)
    failed = []
    with tempfile.TemporaryDirectory(prefix="bench_readme_") as work:
        run = Run(args, Path(work))
        if CENSUS_SECTIONS & set(args.sections):  # compiled (or loaded) now: no bench waits for numba
            run.command(sys.executable, "-m", "stereo_depth.cli", "compile")
        header, measured_on = machine_header()
        print(header + "\n")
        if args.quick:
            print("--quick: fewer repeats and frames; these figures are noise\n")
        for heading in (heading for heading in SECTIONS if heading in args.sections):
            print(f"## {heading}\n\n{measured_on}\n", flush=True)
            try:
                ok = SECTIONS[heading](run)
            except (KeyError, ValueError, OSError) as error:  # a report it cannot read: the other sections still run
                print(f"(failed: {type(error).__name__}: {error})")
                ok = False
            if not ok:
                failed.append(heading)
            print(flush=True)
    os.close(lock)
    if failed:
        print(f"ERROR: a bench failed in: {', '.join(failed)} (its output is above)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
