"""Where the census core's fused kernel spends its time, by kind of inner loop (needs Linux `perf` and `objdump`).

numba's machine code has no symbols perf can read, so this runs the `quality` profile's matcher (census_sgm,
`--paths`, the rectified 640x480 EuRoC pair, 128 disparities) for `--frames` frames in a child
process under `perf record`; the child then copies every anonymous executable mapping (the JIT code) to a
file. The parent maps perf's samples onto those copies, disassembles them (`objdump -b binary`) and gives
each sampled instruction the kind of the nearest instruction that marks one, at most `MARK_REACH`
instructions away (a sample often lands on a load or an add beside the instruction that makes it what it
is). Loops are not the unit: with the disparity count a constant, LLVM unrolls a pixel's 128-disparity
loops completely, so the path updates sit in the pixel loop's body, beside the sums.

  * Hamming costs: a popcount (PSHUFB nibble table + PSADBW, POPCNT, or VPOPCNTQ);
  * selection: unsigned word minima (PMINUW), the winner search on S;
  * path updates: unsigned byte minima (PMINUB), the SGM recurrence on uint8 path costs;
  * sums S: byte-to-word widening (PMOVZXBW), the paths' costs added per pixel;
  * other code: no such instruction nearby (loop control, addressing, scalar work).

Shares of the samples in the JIT code (the census core's kernels; OpenCV and Python are left out).
Set a level's variables from bench/lib/simd.py (SIMD_ENV) to see another SIMD level.

    .venv/bin/python bench/kernel_profile.py [--paths 6 5] [--frames 20] [--markdown]
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row

KINDS = (  # (name, instructions that mark it), checked in this order
    ("Hamming costs", ("psadbw", "popcnt")),
    ("selection", ("pminuw",)),
    ("path updates", ("pminub",)),
    ("sums S", ("pmovzxbw",)),
)
MARK_REACH = 12  # instructions either side of a sample searched for a marking one


def child(paths: int, frames: int, out: Path) -> None:
    """Run the frames, then copy the JIT code (anonymous r-x mappings) to `out`/<start address hex>.bin."""
    from pipeline_stages import rectified_pair

    from stereo_depth.core.matching import create_matcher
    from stereo_depth.core.params import make_params

    left, right = rectified_pair()
    matcher = create_matcher(make_params("quality", {"disparity_range": 128, "census_paths": paths}))
    for _ in range(frames + 1):  # the first loads or compiles the kernels
        matcher.compute(left, right)
    for line in Path("/proc/self/maps").read_text().splitlines():
        fields = line.split()
        if fields[1].startswith("r-x") and len(fields) == 5:
            start, end = (int(x, 16) for x in fields[0].split("-"))
            (out / f"{start:x}.bin").write_bytes(ctypes.string_at(start, end - start))


def instructions(code: Path) -> list[tuple[int, str]]:
    """(offset, instruction) of a JIT code copy, as objdump disassembles it."""
    listing = subprocess.run(
        ["objdump", "-D", "-b", "binary", "-m", "i386:x86-64", "--no-show-raw-insn", str(code)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    matches = (re.match(r"\s+([0-9a-f]+):\s+(.*)", line) for line in listing.splitlines())
    return [(int(m.group(1), 16), m.group(2)) for m in matches if m]


def kind_of(instruction: str) -> str | None:
    """The kind an instruction marks, if any."""
    mnemonic = instruction.split()[0] if instruction.split() else ""
    return next((name for name, marks in KINDS if any(mark in mnemonic for mark in marks)), None)


def shares(samples: collections.Counter[tuple[Path, int]], codes: list[Path]) -> dict[str, float]:
    """Share of the JIT samples per kind: the nearest marking instruction's, else "other code"."""
    by_kind: collections.Counter[str] = collections.Counter()
    for code in codes:
        listing = instructions(code)
        kinds = [kind_of(instruction) for _, instruction in listing]
        index = {offset: i for i, (offset, _) in enumerate(listing)}
        for (sampled, offset), n in samples.items():
            if sampled != code or offset not in index:
                continue
            i = index[offset]
            near = (kinds[j] for step in range(MARK_REACH + 1) for j in (i - step, i + step) if 0 <= j < len(kinds))
            by_kind[next((kind for kind in near if kind), "other code")] += n
    total = sum(by_kind.values())
    return {name: n / total for name, n in by_kind.items()} if total else {}


def profile(paths: int, frames: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        data = work / "perf.data"
        command = [sys.executable, __file__, "--child", str(paths), "--frames", str(frames), "--out", str(work)]
        subprocess.run(["perf", "record", "-q", "-o", str(data), "--", *command], check=True)
        ips = subprocess.run(
            ["perf", "script", "-i", str(data), "-F", "ip"], capture_output=True, text=True, check=True
        )
        codes = sorted(work.glob("*.bin"))
        ranges = [(int(code.stem, 16), int(code.stem, 16) + code.stat().st_size, code) for code in codes]
        samples: collections.Counter[tuple[Path, int]] = collections.Counter()
        for line in ips.stdout.split():
            ip = int(line, 16)
            for start, end, code in ranges:
                if start <= ip < end:
                    samples[(code, ip - start)] += 1
                    break
        return shares(samples, codes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paths", type=int, nargs="+", default=[6, 5])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    if "--child" in sys.argv:
        args = parser.parse_args()
        child(args.child, args.frames, args.out)
        return
    args = parse_bench_arguments(parser)
    missing = [tool for tool in ("perf", "objdump") if shutil.which(tool) is None]
    if missing:
        raise SystemExit(f"kernel_profile.py needs {' and '.join(missing)} (Linux perf, binutils)")
    runs = {paths: profile(paths, args.frames) for paths in args.paths}
    names = [name for name, _ in KINDS] + ["other code"]
    columns = ("part of the kernel", *(f"{paths} paths" for paths in args.paths))
    print(f"640x480 EuRoC pair, 128 disparities, {args.frames} frames")
    print(table_header(columns) if args.markdown else "  ".join(columns))
    for name in names:
        row = (name, *(f"{100 * runs[p].get(name, 0.0):.0f}%" for p in args.paths))
        print(table_row(row) if args.markdown else "  ".join(row))


if __name__ == "__main__":
    main()
