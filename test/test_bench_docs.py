"""bench/ is a toolkit, and docs/performance.md is written by one command from one run.

`make bench-docs` (bench/performance_docs.py) reruns the benches and overwrites docs/performance.md and
the README's performance-at-a-glance table: every table names its machine, rows that need the C++
anchor or the external scenes are left out with a note when those are not given (never filled from an
earlier run), and no bench reaches for a folder outside the repository. No figure is asserted.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
sys.path.insert(0, str(BENCH))
import performance_docs  # noqa: E402
from lib.simd import SIMD_ENV  # noqa: E402

MEASURED_ON = "Measured on: CPU X, 2 usable of 2 cores; numba AVX2 (256-bit), OpenCV up to AVX2; 2030-01-01"
README = "# r\n\nbefore\n\n{begin}\nan old table\n{end}\n\nafter\n"


def scripts() -> list[str]:
    return sorted(path.name for path in BENCH.glob("*.py"))


def section(slug: str, text: str = "", left_out: str = "") -> performance_docs.Section:
    return performance_docs.Section(performance_docs.BY_SLUG[slug], text, left_out=left_out)


def options(**given: object) -> argparse.Namespace:
    defaults: dict[str, object] = {"quick": True, "anchor": None, "data": None}
    return argparse.Namespace(**(defaults | given))


def test_bench_holds_at_most_14_scripts_and_its_readme_lists_each() -> None:
    listed = (BENCH / "README.md").read_text()
    assert len(scripts()) <= 14, scripts()
    assert [name for name in scripts() if f"| `{name}` |" not in listed] == []
    ran = {re.match(r"bench/(\w+\.py)", question.command) for question in performance_docs.QUESTIONS}
    assert {match.group(1) for match in ran if match} <= set(scripts())


def test_no_bench_reaches_outside_the_repository_or_tells_a_story() -> None:
    outside = re.compile(r"parent.*shared|\.\./shared")
    story = re.compile(r"issue [0-9]|until 20[0-9]{2}|later that day", re.IGNORECASE)
    for path in [*BENCH.rglob("*.py"), *BENCH.rglob("*.md")]:
        text = path.read_text()
        assert not outside.search(text), path
        assert not story.search(text), path


def test_the_page_says_how_to_measure_and_names_the_machine_above_every_table() -> None:
    sections = [
        section("pipeline-stages", "caption:\n\n| profile | node / bare |\n|---|---|\n| default | 1.11x |"),
        section("against-the-c-chain", left_out="needs the anchor: `--anchor DIR`"),
    ]
    page = performance_docs.docs_page(sections, "CPU: X", MEASURED_ON, options())
    assert page.index("## How to measure") < page.index("## Contents") < page.index("## Per frame")
    assert "- [Per frame: the node's own work against the bare OpenCV calls](#pipeline-stages)\n" in page
    assert "(#against-the-c-chain) (left out: needs the anchor" in page
    measured = page.split("## Per frame: the node's own work against the bare OpenCV calls\n")[1]
    assert measured.lstrip().startswith(f"{MEASURED_ON} (`.venv/bin/python bench/pipeline_stages.py`)")
    assert "Left out of this run: needs the anchor: `--anchor DIR`." in page
    assert "these figures are noise" in page  # --quick says so


def test_the_anchor_and_data_rows_are_left_out_without_their_folders(tmp_path: Path) -> None:
    run = performance_docs.Run(options(), tmp_path)
    for slug in ("against-the-c-chain", "profiles-on-middlebury-and-kitti", "confidence"):
        measured = performance_docs.measure(performance_docs.BY_SLUG[slug], run)
        assert measured.left_out and not measured.text and not measured.failed, slug
    assert "--anchor DIR" in performance_docs.measure(performance_docs.BY_SLUG["against-the-c-chain"], run).left_out
    assert "--data DIR" in performance_docs.measure(performance_docs.BY_SLUG["confidence"], run).left_out


def test_the_readme_table_is_rewritten_between_its_markers_only() -> None:
    begin, end = performance_docs.GLANCE_BEGIN, performance_docs.GLANCE_END
    text = "| profile | size | node / bare |\n|---|---|---|\n| fast | 640x480 | 1.30x |\n| default | 640x480 | 1.11x |"
    sections = [section("pipeline-stages", text), section("against-the-c-chain", left_out="needs the anchor")]
    table = performance_docs.glance_table(sections, MEASURED_ON)
    readme = performance_docs.with_glance(README.format(begin=begin, end=end), table)
    before, inside = readme.split(begin)
    inside, after = inside.split(end)
    assert before == "# r\n\nbefore\n\n" and after == "\n\nafter\n"
    assert "an old table" not in inside and MEASURED_ON in inside
    assert "| 1.11x | [Per frame" in inside  # the default row's cell, not the first row's
    anchor = "| case | | latency vs C++ |\n|---|---|---|\n| BM 640x480, disparity only | C++ | 1.00x (baseline) |\n"
    anchor += "| | stereo_node | 0.74x |"
    table = performance_docs.glance_table([section("against-the-c-chain", anchor)], MEASURED_ON)
    assert "disparity only | 0.74x |" in table  # our row below the C++ baseline's
    assert "Left out of this run" in inside and "C++ stereo_image_proc" in inside
    with pytest.raises(ValueError, match="markers"):
        performance_docs.with_glance("# a README without the markers\n", table)


def test_make_bench_docs_overwrites_the_page_with_this_run_only(tmp_path: Path) -> None:
    """A real run of the cheapest question, into a page that holds an earlier run's figure."""
    docs, readme = tmp_path / "performance.md", tmp_path / "README.md"
    docs.write_text("| an earlier run | 9.99x |\n")
    begin, end = performance_docs.GLANCE_BEGIN, performance_docs.GLANCE_END
    readme.write_text(README.format(begin=begin, end=end))
    command = [sys.executable, str(BENCH / "performance_docs.py"), "--quick", "--docs", str(docs), "--readme"]
    command += [str(readme), "--questions", "left-right-check", "confidence"]
    subprocess.run(command, check=True, cwd=ROOT, capture_output=True, timeout=600)
    page = docs.read_text()
    assert "9.99x" not in page
    assert "## What the left-right check keeps" in page and "| tsukuba | census_sgm |" in page
    assert "Left out of this run: needs the Middlebury and KITTI scenes: `--data DIR`." in page
    assert readme.read_text().startswith("# r\n\nbefore\n\n") and "an old table" not in readme.read_text()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["README.md", "performance.md"]  # no temporary


def test_a_failed_bench_is_reported_and_its_machine_header_dropped(capsys: pytest.CaptureFixture[str]) -> None:
    """The machine is named on each section's line; a bench's own header (its first '# ' lines) is dropped."""
    script = "print('# CPU: x'); print('# numba SIMD: y'); print(); print('caption'); print('| a |'); print('# b')"
    assert performance_docs.forward_markdown([sys.executable, "-c", script])
    assert capsys.readouterr().out == "caption\n| a |\n# b\n"
    assert not performance_docs.forward_markdown([sys.executable, "-c", "raise SystemExit(3)"])
    assert "failed: exit 3" in capsys.readouterr().out


@pytest.mark.skipif("*AVX2" not in cv2.getCPUFeaturesLine(), reason="measuring AVX2 needs an AVX2 machine")
@pytest.mark.parametrize("level", ["avx2", "128"])
def test_simd_option_makes_numba_and_opencv_use_that_level(level: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """What --simd sets, as the run's machine lines report it (a fresh process, as every bench is)."""
    for name in [name for name in os.environ if name.startswith(("NUMBA_", "OPENCV_CPU"))]:
        monkeypatch.delenv(name)
    for name, value in SIMD_ENV[level].items():
        monkeypatch.setenv(name, value)
    header, measured_on = performance_docs.machine_header()
    numba, opencv = {"avx2": ("AVX2 (256-bit)", "AVX2"), "128": ("SSE4.2 (128-bit)", "SSE4.2")}[level]
    assert f"numba SIMD: {numba}" in header
    assert f"numba {numba}, OpenCV up to {opencv};" in measured_on
