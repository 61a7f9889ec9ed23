"""Markdown tables: a bench run with --markdown prints its figures as the rows of a GitHub markdown table,
which `make bench-docs` (bench/performance_docs.py) puts into docs/performance.md as they are."""

from __future__ import annotations

import argparse
from collections.abc import Iterable

from stereo_depth.machine import print_machine


def table_row(cells: Iterable[object]) -> str:
    return "| " + " | ".join(str(cell) for cell in cells) + " |"


def table_header(columns: Iterable[str]) -> str:
    """After an empty line: a table must not continue a caption's paragraph."""
    names = list(columns)
    return "\n" + table_row(names) + "\n|" + "|".join("---" for _ in names) + "|"


def times(ratio: float) -> str:
    """A ratio against the baseline measured in the same run."""
    return f"{ratio:.2f}x"


def ratio(value: float, baseline: float) -> float:
    """value / baseline; NaN where the baseline is 0 (a run that delivered nothing)."""
    return value / baseline if baseline else float("nan")


def parse_bench_arguments(parser: argparse.ArgumentParser, markdown: str = "a markdown table") -> argparse.Namespace:
    """How a bench starts: `--markdown` added, its arguments read, then the
    machine header printed before any figure."""
    parser.add_argument("--markdown", action="store_true", help=markdown)
    args = parser.parse_args()
    print_machine()
    return args
