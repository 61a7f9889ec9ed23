"""One clear log line per kind of input problem: logged when first seen, then at most once a period.

rclpy's `throttle_duration_sec` throttles per call site: after one bad image, a different problem a
second later (a broken calibration, a silent camera) would go unseen for the rest of the period. Here
each kind of problem (its text with the numbers taken out, so changing stamps or sizes do not make a
new kind) has its own period, and the line that ends a quiet period says how many were left out.
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass
from typing import Any

from stereo_depth.ros.diagnostics import NodeDiagnostics

PERIOD_S = 5.0
MAX_KINDS = 64  # distinct kinds remembered; a flood of new kinds cannot grow memory
_NUMBERS = re.compile(r"-?\d+(\.\d+)?(e[-+]?\d+)?")


@dataclass
class _Seen:
    logged_at: float
    suppressed: int = 0


class ProblemLog:
    """Thread-safe: subscription callbacks, the worker and timers all report here."""

    def __init__(self, logger: Any, diagnostics: NodeDiagnostics, period_s: float = PERIOD_S) -> None:
        self._logger = logger
        self._diagnostics = diagnostics
        self._period_s = period_s
        self._lock = threading.Lock()
        self._seen: dict[str, _Seen] = {}
        self._once: set[str] = set()

    def skipped(self, text: str) -> None:
        """Input was refused (frame or message skipped): diagnostics' last error and a warning."""
        self._diagnostics.error(text)
        self.warn(text)

    def warn(self, text: str) -> None:
        """Something to fix that diagnostics reports on its own (a silent input)."""
        line = self._due(text, _NUMBERS.sub("#", text), time.monotonic())
        if line is not None:
            self._logger.warning(line)  # rclpy wants one severity per call site: one call each

    def warn_once(self, text: str) -> None:
        """Something that holds for every frame and costs only part of the outputs (a calibration with no
        baseline: disparity, but no depth): one warning for the node's lifetime, not one per period."""
        kind = _NUMBERS.sub("#", text)
        with self._lock:
            if kind in self._once:
                return
            self._once.add(kind)
        self._logger.warning(text)

    def info(self, text: str, kind: str | None = None) -> None:
        """Worth knowing, nothing lost (a new calibration, stamps restarting). `kind` tells apart what
        reads alike (two calibrations that differ only in D); by default, the text without numbers."""
        line = self._due(text, kind or _NUMBERS.sub("#", text), time.monotonic())
        if line is not None:
            self._logger.info(line)

    def _due(self, text: str, kind: str, now: float) -> str | None:
        """The line to log now, or None while this kind is being throttled."""
        with self._lock:
            seen = self._seen.get(kind)
            if seen is not None and now - seen.logged_at < self._period_s:
                seen.suppressed += 1
                return None
            suppressed = seen.suppressed if seen is not None else 0
            self._forget_old(now)
            self._seen[kind] = _Seen(now)
        if suppressed:
            return f"{text} ({suppressed} more like it since the last report)"
        return text

    def _forget_old(self, now: float) -> None:
        if len(self._seen) < MAX_KINDS:
            return
        self._seen = {k: s for k, s in self._seen.items() if now - s.logged_at < self._period_s}
        if len(self._seen) >= MAX_KINDS:
            self._seen.clear()
