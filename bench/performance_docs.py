"""`make bench-docs`: docs/performance.md written from one run, and the README's performance-at-a-glance table.

Runs the benches one after another while holding the CPU lock (/tmp/stereo_depth_cpu.lock, as `flock`
takes it: no other bench shares the cores meanwhile) and writes docs/performance.md: how to measure, then
one section per question, each with the machine line (CPU, cores, SIMD levels, date) and the bench's
markdown table. Every table carries a ratio against a baseline measured in the same run. The page is
overwritten each time: it holds this run's figures only. The README's table between the markers
`<!-- performance-at-a-glance:begin -->` and `<!-- performance-at-a-glance:end -->` is rewritten from
the same run.

Rows that need the ROS 1 C++ stereo_image_proc anchor or scenes outside the repository are measured only
when given `--anchor DIR` (the anchor's folder, with its run.sh) or `--data DIR` (a folder of scene sets:
middlebury*/SCENE, kitti*/SCENE, with ground truth); without them those rows are left out with a note.

--quick runs everything with fewer repeats and frames, to check that it works (its figures are noise).
--simd measures another SIMD level on this machine: numba compiles for that CPU (with a cache folder
of its own) and OpenCV's dispatcher leaves out the wider levels (OPENCV_CPU_DISABLE).

    make bench-docs [ARGS="--quick --anchor DIR --data DIR --simd avx2"]
    .venv/bin/python bench/performance_docs.py [--quick] [--simd native|avx2|128] [--questions SLUG ...]
        [--anchor DIR] [--data DIR] [--docs PATH] [--readme PATH]
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from lib import e2e_tables
from lib.simd import SIMD_ENV, simd_env
from lib.table import table_header, table_row

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
CPU_LOCK = Path("/tmp/stereo_depth_cpu.lock")
GLANCE_BEGIN = "<!-- performance-at-a-glance:begin -->"
GLANCE_END = "<!-- performance-at-a-glance:end -->"
BUNDLED_SCENES = tuple(f"test/data/scenes/{name}" for name in ("artl", "cones", "tsukuba"))
# the temporal filter's longer sequences, from --data: scenes with ground truth, and real static recordings
TEMPORAL_DATA_SCENES = (
    "middlebury2006/aloe",
    "middlebury2006/baby1",
    "middlebury2003/teddy",
    "middlebury2005/books",
    "middlebury2006/rocks1",
    "middlebury2006/bowling2",
    "middlebury2001/venus",
)
TEMPORAL_RECORDINGS = "static_recordings"  # bench/README.md says how to build it


class RowsLeftOutError(Exception):
    """A question (or some of its rows) needs the anchor or the data sets and was not given them."""


@dataclass
class Run:
    """What each question needs: the command line's options and a scratch folder for the benches' reports."""

    args: argparse.Namespace
    work: Path
    notes: list[str] = field(default_factory=list)  # rows left out of the question being measured

    def bench(self, script: str, *arguments: str, full: tuple[str, ...] = (), quick: tuple[str, ...] = ()) -> bool:
        """A bench with these arguments, then `full` (repeats and frames for the page: a run of minutes on a
        2-core machine) or, with --quick, `quick`, and --markdown; its output without its machine header
        (the page prints the machine on each section's line)."""
        sizes = quick if self.args.quick else full
        return forward_markdown([sys.executable, str(BENCH / script), *arguments, *sizes, "--markdown"])

    def command(self, *arguments: str) -> bool:
        """A command whose output is progress, not figures (stderr)."""
        print(f"$ {' '.join(arguments)}", file=sys.stderr, flush=True)
        return subprocess.run(arguments, stdout=sys.stderr, check=False).returncode == 0

    def data_scenes(self) -> list[str]:
        """The scenes with ground truth under --data: Middlebury and KITTI (--quick: 4)."""
        if self.args.data is None:
            raise RowsLeftOutError("needs the Middlebury and KITTI scenes: `--data DIR`")
        found = [p for p in sorted(self.args.data.glob("*/*/")) if p.parent.name.startswith(("middlebury", "kitti"))]
        if not found:
            raise RowsLeftOutError(f"no middlebury*/SCENE or kitti*/SCENE folder under --data {self.args.data}")
        return [str(p) for p in (found[:4] if self.args.quick else found)]

    def anchor(self) -> Path:
        if self.args.anchor is None:
            raise RowsLeftOutError(
                "needs the ROS 1 C++ stereo_image_proc anchor: `--anchor DIR` (the folder of its run.sh)"
            )
        return Path(self.args.anchor)


def forward_markdown(command: list[str]) -> bool:
    """Runs a bench and prints its output but its leading machine header; False (and a note) if it failed."""
    print(f"$ {' '.join(command)}", file=sys.stderr, flush=True)
    with subprocess.Popen(command, stdout=subprocess.PIPE, text=True, cwd=ROOT) as child:
        assert child.stdout is not None
        header = True
        for line in child.stdout:
            if header and (line.startswith("# ") or not line.strip()):
                continue  # the bench's machine header: the same machine as the section's line
            header = False
            print(line, end="", flush=True)
    if child.returncode != 0:
        print(f"\n(failed: exit {child.returncode}; the bench's messages went to stderr)")
    return child.returncode == 0


@dataclass(frozen=True)
class Pick:
    """One row of the README's at-a-glance table: a cell of one of a question's tables."""

    label: str
    row: str  # the first row whose first two cells contain this text
    column: str  # the column of this header, else the last whose header contains this text
    below: int = 0  # the row this many rows below that one
    table: int = 0


@dataclass(frozen=True)
class Question:
    slug: str  # the section's anchor in docs/performance.md
    title: str
    command: str  # what to run for this table alone
    measure: Callable[[Run], bool]
    glance: tuple[Pick, ...] = ()


def anchor_comparison(run: Run) -> bool:
    return e2e_tables.anchor(run.work, run.args.quick, run.anchor())


def node_rate(run: Run) -> bool:
    return e2e_tables.quality(run.work, run.args.quick)


def input_pairing(run: Run) -> bool:
    return e2e_tables.pairing(run.work, run.args.quick)


def repeated(script: str, flag: str, *, full: str, quick: str) -> Callable[[Run], bool]:
    """A question answered by one bench whose only argument is how often it repeats (`flag`)."""
    return lambda run: run.bench(script, full=(flag, full), quick=(flag, quick))


pipeline_stages = repeated("pipeline_stages.py", "--repeat", full="8", quick="2")


census_simd = repeated("simd_match_ratio.py", "--repeat", full="7", quick="2")


bm_simd = repeated("bm_kernels.py", "--repeat", full="9", quick="2")


def kernel_profile(run: Run) -> bool:
    if not (shutil.which("perf") and shutil.which("objdump")):
        run.notes.append("Left out: needs Linux perf and objdump on this machine.")
        return True
    return run.bench("kernel_profile.py", full=("--frames", "8"), quick=("--frames", "2"))


clouds = repeated("cloud_outputs.py", "--repeat", full="10", quick="2")


compressed_depth = repeated("compressed_depth.py", "--repeat", full="4", quick="2")


compressed_input = repeated("compressed_input.py", "--repeat", full="10", quick="2")


def temporal(run: Run) -> bool:
    scenes, recordings = list(BUNDLED_SCENES), []
    if run.args.data is None:
        run.notes.append(
            "Left out: the rows of "
            + ", ".join(TEMPORAL_DATA_SCENES)
            + " and the static recordings (needs `--data DIR`)."
        )
    else:
        scenes += [str(run.args.data / name) for name in TEMPORAL_DATA_SCENES if (run.args.data / name).is_dir()]
        if (run.args.data / TEMPORAL_RECORDINGS).is_dir():
            recordings = ["--data", str(run.args.data / TEMPORAL_RECORDINGS)]
        else:
            run.notes.append(f"Left out: the static recordings (no `{TEMPORAL_RECORDINGS}/` in `--data`).")
    sizes = {"full": ("--frames", "30", "--warm-up", "8"), "quick": ("--frames", "12", "--warm-up", "4")}
    return run.bench("temporal.py", "--scenes", *scenes, *recordings, **sizes)


def fleet(run: Run) -> bool:
    return run.bench("fleet.py", full=("--frames", "60"), quick=("--frames", "20"))


def offline(run: Run) -> bool:
    arguments = ("--profiles", "stereo_image_proc", "--sizes", "640x480", "--repeats", "1")
    return run.bench("offline_process.py", *arguments, full=("--frames", "60"), quick=("--frames", "20"))


def profiles_bundled(run: Run) -> bool:
    return run.bench("accuracy.py", "profiles", *BUNDLED_SCENES, quick=("--repeat", "1"))


def profiles_data(run: Run) -> bool:
    return run.bench("accuracy.py", "profiles", *run.data_scenes(), full=("--repeat", "2"), quick=("--repeat", "1"))


def confidence(run: Run) -> bool:
    return run.bench("accuracy.py", "confidence", *run.data_scenes())


def left_right_check(run: Run) -> bool:
    return run.bench("accuracy.py", "left-right", *BUNDLED_SCENES)


QUESTIONS = (
    Question(
        "against-the-c-chain",
        "Against the C++ chain (ROS 1 stereo_image_proc), end to end over DDS",
        "bench/e2e_dds.py --anchor DIR --profiles all --cases ...",
        anchor_comparison,
        (
            Pick(
                "Latency against C++ stereo_image_proc, BM 640x480, disparity only",
                "BM 640x480, disparity only",
                "vs C++",
                below=1,
            ),
            Pick(
                "Latency against C++ stereo_image_proc, BM 640x480 with 16-byte points2 (disparity / points2)",
                "BM 640x480",
                "vs C++",
                below=1,
            ),
        ),
    ),
    Question(
        "node-rate-by-profile",
        "The node's rate with the census core",
        "bench/e2e_dds.py --cases default_vga_30_128 quality_vga_30_128 --profiles all",
        node_rate,
        (
            Pick(
                "stereo_node rate, `quality` against `default` (640x480 at 30 Hz, 128 disparities)",
                "`quality`",
                "vs `default`",
            ),
        ),
    ),
    Question(
        "input-pairing-over-dds",
        "Input pairing and queue length over DDS",
        "bench/e2e_dds.py --pairing",
        input_pairing,
        (
            Pick(
                "Latency against bare rclpy, disparity / points2 (camera_info first, no profile exported)",
                "camera_info first (left",
                "vs bare",
            ),
        ),
    ),
    Question(
        "pipeline-stages",
        "Per frame: the node's own work against the bare OpenCV calls",
        "bench/pipeline_stages.py",
        pipeline_stages,
        (Pick("A frame's work, `default` 640x480, against the bare OpenCV calls", "default", "node / bare"),),
    ),
    Question(
        "census-core-at-each-simd-level",
        "The census core against OpenCV's SGBM 3-way at each SIMD level",
        "bench/simd_match_ratio.py",
        census_simd,
        (
            Pick(
                "`quality` (census core) match time against `default` (SGBM 3-way), native SIMD",
                "native",
                "quality / default",
            ),
        ),
    ),
    Question(
        "bm-kernels-at-each-simd-level",
        "Our BM kernels against OpenCV's StereoBM at each SIMD level",
        "bench/bm_kernels.py",
        bm_simd,
        (
            Pick(
                "Our BM kernels against OpenCV's StereoBM, one thread, native SIMD", "native", "ours / OpenCV, 1 thread"
            ),
        ),
    ),
    Question(
        "inside-the-census-kernel",
        "Inside the census core's fused kernel, by kind of work",
        "bench/kernel_profile.py",
        kernel_profile,
    ),
    Question("clouds", "What a cloud costs per frame", "bench/cloud_outputs.py", clouds),
    Question(
        "compressed-depth", "What depth/compressedDepth costs per frame", "bench/compressed_depth.py", compressed_depth
    ),
    Question("compressed-input", "What compressed input costs", "bench/compressed_input.py", compressed_input),
    Question("temporal-filter", "The temporal filter over time", "bench/temporal.py --scenes ...", temporal),
    Question("many-bags", "Many bags on local workers", "bench/fleet.py", fleet),
    Question(
        "offline-processing",
        "Offline: `stereo-depth process` against a bare loop",
        "bench/offline_process.py --profiles stereo_image_proc --sizes 640x480",
        offline,
        (
            Pick(
                "`stereo-depth process` frames/s against a bare OpenCV loop (640x480, to MCAP)",
                "stereo_image_proc",
                "vs",
            ),
        ),
    ),
    Question(
        "profiles-on-the-bundled-scenes",
        "The profiles on the bundled scenes",
        "bench/accuracy.py profiles test/data/scenes/{artl,cones,tsukuba}",
        profiles_bundled,
    ),
    Question(
        "profiles-on-middlebury-and-kitti",
        "The profiles on Middlebury and KITTI",
        "bench/accuracy.py profiles DATA/middlebury*/* DATA/kitti*/*",
        profiles_data,
        (Pick("Mean bad-2 of `quality` on Middlebury and KITTI (`default`: see the table)", "`quality`", "bad-2"),),
    ),
    Question(
        "confidence",
        "What the confidence is worth",
        "bench/accuracy.py confidence DATA/middlebury*/* DATA/kitti*/*",
        confidence,
    ),
    Question(
        "left-right-check",
        "What the left-right check keeps",
        "bench/accuracy.py left-right test/data/scenes/{artl,cones,tsukuba}",
        left_right_check,
    ),
)
BY_SLUG = {question.slug: question for question in QUESTIONS}

# those that run the census core (or numba kernels beside it): numba's kernels are built before they run
NUMBA_FREE = {"input-pairing-over-dds", "compressed-input", "many-bags"}


@dataclass(frozen=True)
class Section:
    question: Question
    text: str  # the bench's captions and tables, or why it was left out
    left_out: str = ""  # the whole section left out: why
    failed: bool = False


def measure(question: Question, run: Run) -> Section:
    """Runs the question's benches, their markdown captured; a section saying why if it was left out."""
    run.notes.clear()
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            ok = question.measure(run)
    except RowsLeftOutError as reason:
        return Section(question, "", left_out=str(reason))
    except (KeyError, ValueError, OSError) as error:  # a report it cannot read: the other questions still run
        return Section(question, f"{captured.getvalue()}\n(failed: {type(error).__name__}: {error})", failed=True)
    text = captured.getvalue().strip()
    if run.notes:
        text += "\n\n" + "\n".join(run.notes)
    return Section(question, text, failed=not ok)


def markdown_tables(text: str) -> list[list[list[str]]]:
    """Each markdown table in the text as rows of cells, its header first (the separator row dropped)."""
    tables: list[list[list[str]]] = []
    previous = ""
    for line in text.splitlines():
        if line.startswith("|") and not re.fullmatch(r"\|(-+\|)+", line):
            if not previous.startswith("|"):
                tables.append([])
            tables[-1].append([cell.strip() for cell in line.strip().strip("|").split("|")])
        previous = line
    return tables


def pick(text: str, wanted: Pick) -> str | None:
    """The cell the pick names, or None where the table lacks it."""
    tables = markdown_tables(text)
    if len(tables) <= wanted.table:
        return None
    header, *rows = tables[wanted.table]
    columns = [index for index, name in enumerate(header) if wanted.column in name]
    if wanted.column in header:
        columns = [header.index(wanted.column)]
    found = [index for index, row in enumerate(rows) if any(wanted.row in cell for cell in row[:2])]
    if not columns or not found or found[0] + wanted.below >= len(rows):
        return None
    row = rows[found[0] + wanted.below]
    return row[columns[-1]] if len(row) > columns[-1] else None


def docs_page(sections: list[Section], machine: str, measured_on: str, args: argparse.Namespace) -> str:
    """docs/performance.md: how to measure, the contents, then a section per question."""
    quick = "\n**--quick: fewer repeats and frames; these figures are noise.**\n" if args.quick else ""
    contents = []
    for section in sections:
        suffix = f" (left out: {section.left_out})" if section.left_out else " (failed)" if section.failed else ""
        contents.append(f"- [{section.question.title}](#{section.question.slug}){suffix}")
    parts = [
        "# Performance",
        "",
        "<!-- Written by `make bench-docs` (bench/performance_docs.py) from one run; do not edit by hand. -->",
        quick,
        "## How to measure",
        "",
        "`make bench-docs` reruns every bench below one after another under the CPU lock "
        "(`/tmp/stereo_depth_cpu.lock`: no other bench shares the cores meanwhile) and rewrites this page and the "
        "README's performance-at-a-glance table. Each table names the machine and the date on its first line and "
        "carries a ratio against a baseline measured in the same run: ratios carry over to other machines better "
        "than times. On a shared or virtual machine, take a quiet moment and compare ratios, not milliseconds.",
        "",
        '- `make bench-docs ARGS="--quick"`: fewer repeats and frames, to check that it works.',
        '- `make bench-docs ARGS="--anchor DIR --data DIR"`: also the rows that need the ROS 1 C++ '
        "stereo_image_proc anchor (DIR holds its `run.sh`) and the Middlebury and KITTI scenes "
        "(DIR holds `middlebury*/SCENE` and `kitti*/SCENE` folders). Without them those rows are left out.",
        '- `make bench-docs ARGS="--simd avx2"` (or `128`): numba and OpenCV at a narrower SIMD level than the '
        "CPU has.",
        '- `make bench-docs ARGS="--questions SLUG ..."`: some sections only (their slugs are the anchors below).',
        "- One bench by itself: `flock /tmp/stereo_depth_cpu.lock .venv/bin/python bench/NAME.py --help`; "
        "[bench/README.md](../bench/README.md) lists them.",
        "- A long run (memory, latency percentiles, drops): `.venv/bin/python bench/soak.py --seconds 600`.",
        "- Experiments whose answer is built into the code, with the figure that decided each: "
        "[design/decisions.md](design/decisions.md).",
        "",
        "This run's machine:",
        "",
        "```",
        machine,
        "```",
        "",
        "## Contents",
        "",
        *contents,
    ]
    for section in sections:
        parts += ["", f'<a id="{section.question.slug}"></a>', "", f"## {section.question.title}", ""]
        if section.left_out:
            parts.append(f"Left out of this run: {section.left_out}.")
            continue
        parts += [f"{measured_on} (`.venv/bin/python {section.question.command}`)", "", section.text]
    return re.sub(r"\n{3,}", "\n\n", "\n".join(parts)).rstrip() + "\n"  # a caption's own blank line


def glance_table(sections: list[Section], measured_on: str) -> str:
    """The README's at-a-glance table: one figure per row, each linking to its section."""
    rows, left_out = [], []
    for section in sections:
        for wanted in section.question.glance:
            figure = None if section.left_out else pick(section.text, wanted)
            if figure is None:
                left_out.append(f"{wanted.label} ({section.left_out or 'not in its table this run'})")
                continue
            link = f"[{section.question.title}](docs/performance.md#{section.question.slug})"
            rows.append(table_row((wanted.label, figure, link)))
    lines = [f"{measured_on} (`make bench-docs`)"]
    if rows:
        lines += [table_header(("question", "this run", "details")), *rows]
    if left_out:
        lines += ["", "Left out of this run (see docs/performance.md): " + "; ".join(left_out) + "."]
    return "\n".join(lines).lstrip("\n")


def with_glance(readme: str, table: str) -> str:
    """The README with the text between the at-a-glance markers replaced by the table."""
    begin, end = readme.find(GLANCE_BEGIN), readme.find(GLANCE_END)
    if begin < 0 or end < begin:
        msg = f"no {GLANCE_BEGIN} ... {GLANCE_END} markers"
        raise ValueError(msg)
    return f"{readme[: begin + len(GLANCE_BEGIN)]}\n{table}\n{readme[end:]}"


def write_atomically(path: Path, text: str) -> None:
    """The new text in a temporary file beside the old one, renamed over it: never half a file."""
    with tempfile.NamedTemporaryFile("w", dir=path.parent, prefix=f".{path.name}.", delete=False) as handle:
        handle.write(text)
    Path(handle.name).replace(path)


def machine_header() -> tuple[str, str]:
    """The machine header and the 'Measured on:' line as the benches see the machine: from a fresh process
    with this run's environment (numba and OpenCV read their SIMD settings when they are imported)."""
    code = "from stereo_depth.machine import measured_on, print_machine; print_machine(); print(measured_on())"
    printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    header, measured_on = printed.strip().rsplit("\n", 1)
    return header.replace("# ", "").strip(), measured_on.rstrip(".")


def hold_cpu_lock() -> int:
    """The lock `flock /tmp/stereo_depth_cpu.lock` takes, held until this process ends."""
    handle = os.open(CPU_LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        print(f"waiting for {CPU_LOCK} (another bench holds it)", file=sys.stderr, flush=True)
        fcntl.flock(handle, fcntl.LOCK_EX)
    return handle


def folder(text: str) -> Path:
    path = Path(text).resolve()
    if not path.is_dir():
        msg = f"{text}: not a folder"
        raise argparse.ArgumentTypeError(msg)
    return path


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats and frames: checks that it works")
    parser.add_argument("--simd", choices=sorted(SIMD_ENV), default="native", help="the SIMD level to measure")
    parser.add_argument("--questions", nargs="+", choices=list(BY_SLUG), default=list(BY_SLUG), metavar="SLUG")
    parser.add_argument("--anchor", type=folder, help="the ROS 1 C++ stereo_image_proc anchor's folder (run.sh)")
    parser.add_argument("--data", type=folder, help="a folder of scene sets with ground truth (middlebury*, kitti*)")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs" / "performance.md", help="the page to write")
    parser.add_argument("--readme", type=Path, default=ROOT / "README.md", help="the README whose table to rewrite")
    args = parser.parse_args()
    if args.anchor is not None and not (args.anchor / "run.sh").is_file():
        parser.error(f"--anchor {args.anchor}: no run.sh there")
    return args


def main() -> int:
    args = parse_arguments()
    if args.simd != "native":  # for every bench this run starts
        os.environ.update(simd_env(args.simd))
    lock = hold_cpu_lock()
    questions = [question for question in QUESTIONS if question.slug in args.questions]
    with tempfile.TemporaryDirectory(prefix="bench_docs_") as work:
        run = Run(args, Path(work))
        if any(question.slug not in NUMBA_FREE for question in questions):  # no bench waits for numba
            run.command(sys.executable, "-m", "stereo_depth.cli", "compile")
        machine, measured_on = machine_header()
        sections = []
        for question in questions:
            print(f"== {question.title}", file=sys.stderr, flush=True)
            sections.append(measure(question, run))
    os.close(lock)
    args.docs.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(args.docs, docs_page(sections, machine, measured_on, args))
    print(f"wrote {args.docs}", file=sys.stderr)
    try:
        write_atomically(args.readme, with_glance(args.readme.read_text(), glance_table(sections, measured_on)))
        print(f"rewrote the at-a-glance table of {args.readme}", file=sys.stderr)
    except (OSError, ValueError) as error:
        print(f"ERROR: {args.readme}: {error}; its at-a-glance table was not rewritten", file=sys.stderr)
        return 1
    failed = [section.question.slug for section in sections if section.failed]
    if failed:
        print(f"ERROR: a bench failed in: {', '.join(failed)} (docs/performance.md says so)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
