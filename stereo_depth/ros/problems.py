"""One clear log line per kind of input problem: logged when first seen, then at most once a period.

rclpy's `throttle_duration_sec` throttles per call site: after one bad image, a different problem a
second later (a broken calibration, a silent camera) would go unseen for the rest of the period. Here
each kind of problem has its own period, and the line that ends a quiet period says how many were left
out. A kind is a key, never the text: the node's own problems name theirs (the problem and its topic),
and an error's is the code path that raised it (`error_key`), so changing stamps or sizes make no new
kind, and the same problem on /cam0 and on /cam1 are two.
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass
from typing import Any

from stereo_depth.ros.diagnostics import NodeDiagnostics

PERIOD_S = 5.0
MAX_KINDS = 64  # distinct kinds remembered; a flood of new kinds cannot grow memory
Key = tuple[str, ...]


def error_key(exc: BaseException) -> Key:
    """An error's kind: its type, and for each error of its cause chain where it was made and every line
    it was raised through. The same bad input takes the same path each time; each input is read on a
    line of its own (frames.decode_frame)."""
    key = [type(exc).__qualname__]
    error: BaseException | None = exc
    while error is not None:
        key.append(getattr(error, "made_at", ""))
        key += (f"{frame.filename}:{frame.lineno}" for frame in traceback.extract_tb(error.__traceback__))
        error = error.__cause__
    return tuple(key)


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
        self._seen: dict[Key, _Seen] = {}
        self._once: set[str] = set()

    def skipped(self, text: str, key: Key) -> None:
        """Input was refused (frame or message skipped): diagnostics' last error and a warning."""
        self._diagnostics.error(text)
        self.warn(text, key)

    def warn(self, text: str, key: Key) -> None:
        """Something to fix that diagnostics reports on its own (a silent input)."""
        line = self._due(text, key, time.monotonic())
        if line is not None:
            self._logger.warning(line)  # rclpy wants one severity per call site: one call each

    def warn_once(self, text: str) -> None:
        """Something that holds for every frame and costs only part of the outputs (a calibration with no
        baseline: disparity, but no depth): one warning for the node's lifetime, not one per period."""
        with self._lock:
            if text in self._once:
                return
            self._once.add(text)
        self._logger.warning(text)

    def info(self, text: str, key: Key) -> None:
        """Worth knowing, nothing lost (a new calibration, stamps restarting)."""
        line = self._due(text, key, time.monotonic())
        if line is not None:
            self._logger.info(line)

    def _due(self, text: str, kind: Key, now: float) -> str | None:
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
