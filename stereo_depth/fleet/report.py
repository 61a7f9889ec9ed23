"""What a fleet run tells: one progress line while it runs, then one line per failure and a JSON report."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

Status = Literal["done", "skipped", "failed", "cancelled"]


@dataclass
class BagReport:
    input: str
    output: str
    status: Status = "cancelled"
    shards: int = 1
    frames_in: int = 0
    frames_out: int = 0
    seconds: float = 0.0  # processing time summed over the bag's tasks
    frames_per_second: float = 0.0
    error: str | None = None
    threads: dict[str, int] = field(default_factory=dict)  # OpenCV / numba threads of its worker


class ProgressLine:
    """Bags done / total, frames, frames/s and failures, redrawn in place on a terminal; on a log
    (not a terminal), one line each time a bag finishes."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.start = time.perf_counter()
        self.terminal = sys.stderr.isatty()

    def update(self, bags: list[BagReport]) -> None:
        finished = [b for b in bags if b.status in ("done", "skipped", "failed")]
        frames = sum(b.frames_out for b in bags)
        failures = sum(b.status == "failed" for b in bags)
        rate = frames / max(time.perf_counter() - self.start, 1e-9)
        line = f"bags {len(finished)}/{self.total}  frames {frames}  {rate:.1f} frames/s  failures {failures}"
        sys.stderr.write(f"\r{line}" if self.terminal else f"{line}\n")
        sys.stderr.flush()

    def close(self) -> None:
        if self.terminal:
            sys.stderr.write("\n")


def write_report(path: Path, bags: list[BagReport], seconds: float) -> None:
    """The JSON report, replaced in one step (a reader never sees half of it)."""
    frames = sum(b.frames_out for b in bags)
    document = {
        "bags": [asdict(b) for b in bags],
        "total": {
            "bags": len(bags),
            "done": sum(b.status == "done" for b in bags),
            "skipped": sum(b.status == "skipped" for b in bags),
            "failed": sum(b.status == "failed" for b in bags),
            "frames_out": frames,
            "seconds": seconds,
            "frames_per_second": frames / seconds if seconds > 0 else 0.0,
        },
    }
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(document, indent=2) + "\n")
    tmp.replace(path)
