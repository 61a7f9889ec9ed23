"""The README's speed figures can be remeasured in one step and say which machine they came from.

`make bench-readme` (bench/readme_figures.py) must rerun every bench the README quotes and print tables
that drop into the README as they are; every speed table in the README names its machine and carries
a ratio against a baseline of the same run. No figure is asserted: the benches print them.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

ROOT = Path(__file__).resolve().parents[1]
# The speed tables live in the README and the docs pages (docs/tuning.md and others)
README = "\n".join(page.read_text() for page in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))])
BENCH = ROOT / "bench"
sys.path.insert(0, str(BENCH))
import readme_figures  # noqa: E402

# Benches the README names without quoting a figure of theirs
WITHOUT_FIGURES = {"soak", "readme_figures"}
SPEED_WORDS = re.compile(r"\bms\b|\bHz\b|frames/s")
RATIO_COLUMN = re.compile(r"\bvs\b| / ")


def readme_tables() -> list[tuple[str, str, str]]:
    """(section heading, text of the section before the table, header row) of every README table."""
    tables = []
    heading, before = "", ""
    lines = README.splitlines()
    for index, line in enumerate(lines):
        if line.startswith("#"):
            heading, before = line, ""
        elif line.startswith("|") and index + 1 < len(lines) and lines[index + 1].startswith("|---"):
            tables.append((heading, before, line))
        before += line + "\n"
    return tables


def test_make_bench_readme_reruns_every_bench_the_readme_quotes() -> None:
    quoted = set(re.findall(r"bench/([a-z0-9_]+)\.py", README)) - WITHOUT_FIGURES
    run = (BENCH / "readme_figures.py").read_text() + (BENCH / "readme_e2e.py").read_text()
    assert quoted, "the README quotes no bench"
    assert sorted(name for name in quoted if f'"{name}.py"' not in run) == []
    assert "bench-readme:" in (ROOT / "Makefile").read_text()


def test_every_speed_table_names_its_machine_and_carries_a_ratio() -> None:
    speed_tables = [t for t in readme_tables() if SPEED_WORDS.search(t[2]) and "option" not in t[2]]
    assert len(speed_tables) >= 10
    for heading, before, header in speed_tables:
        assert "Measured on:" in before, f"{heading}: no 'Measured on:' line above {header}"
        assert RATIO_COLUMN.search(header), f"{heading}: no ratio column in {header}"


def test_a_bench_prints_its_readme_table_in_markdown() -> None:
    """compressed_input's markdown header is the README's, and every row has a ratio against raw input."""
    command = [sys.executable, str(BENCH / "compressed_input.py"), "--repeat", "1", "--markdown"]
    printed = subprocess.run(command, capture_output=True, text=True, check=True, cwd=ROOT, timeout=300).stdout
    rows = [line for line in printed.splitlines() if line.startswith("|")]
    header, separator, *body = rows
    assert f"{header}\n{separator}\n" in README
    assert len(body) == 6
    for row in body:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        assert len(cells) == header.count("|") - 1
        assert re.fullmatch(r"\d+\.\d\dx", cells[-1]), row
        if cells[1] == "raw":
            assert cells[-1] == "1.00x"


def test_the_tables_are_printed_without_each_bench_machine_header(capsys: pytest.CaptureFixture[str]) -> None:
    """The machine is printed once for the whole run; a bench's own header (its first '# ' lines) is dropped."""
    script = "print('# CPU: x'); print('# numba SIMD: y'); print(); print('caption'); print('| a |'); print('# b')"
    assert readme_figures.forward_markdown([sys.executable, "-c", script])
    assert capsys.readouterr().out == "caption\n| a |\n# b\n"
    assert not readme_figures.forward_markdown([sys.executable, "-c", "raise SystemExit(3)"])
    assert "failed: exit 3" in capsys.readouterr().out


@pytest.mark.skipif("*AVX2" not in cv2.getCPUFeaturesLine(), reason="measuring AVX2 needs an AVX2 machine")
@pytest.mark.parametrize("level", ["avx2", "128"])
def test_simd_option_makes_numba_and_opencv_use_that_level(level: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """What --simd sets, as the run's header reports it (a fresh process, as every bench is)."""
    for name in [name for name in os.environ if name.startswith(("NUMBA_", "OPENCV_CPU"))]:
        monkeypatch.delenv(name)
    for name, value in readme_figures.SIMD_ENV[level].items():
        monkeypatch.setenv(name, value)
    header, measured_on = readme_figures.machine_header()
    numba, opencv = {"avx2": ("AVX2 (256-bit)", "AVX2"), "128": ("SSE4.2 (128-bit)", "SSE4.2")}[level]
    assert f"# numba SIMD: {numba}" in header
    assert f"numba {numba}, OpenCV up to {opencv};" in measured_on
