"""Temporal filter: per-pixel disparity over the last few frames, so a match seen once never becomes a point.

Navigation stacks mark what a depth frame shows; a pixel that is wrong in one frame is a ghost obstacle.
For each pixel the filter keeps its disparity in the last `history` frames (HOLE where invalid) and,
per frame, looks at two candidates:

- a: the newest valid value of the last BRIDGED_FRAMES + 1 frames (a hole of up to 2 frames keeps the
  last value; older values never stand in, so an object that left leaves a trail of at most 2 frames);
- b: the previous frame's value, when a is this frame's.

a is output when at least `persistence` of the remembered frames agree with it within `delta` px
(RealSense's "valid in k of the last n": a wrong match seen once has no support) and no more disagree
than agree (a pixel that flips between two values is not output); else b, when it differs from a and
passes the same test (a new value seen once, an outlier or the first frame of a change, shows the
previous one); else nothing. The value is an exponential average of the agreeing frames only (`alpha`,
the newest frame's weight; older frames' weights fall by 1 - alpha per frame), each also weighted by the
matcher's confidence when it gives one (census_sgm): a value that differs by more than `delta` restarts
the average.

The output is a function of the last frames alone (no recursion over the whole stream), so a bag cut into
shards gives bit-identical results once each shard is fed `lead_in_frames` frames before its first.
Everything restarts (the history is emptied) when the stamp goes back (a looping bag, a restarted
driver), when more than `GAP_PERIODS` frame periods pass without a frame, when the calibration or the
image size changes, and, with `motion_reset`, when more than that share of the pixels valid in both
frames changed by more than `delta` since the previous frame (the camera jumped: everything changed).
ROS-free; the kernels are numba-compiled on first use (census_sgm's dependency), then cached.
"""

from __future__ import annotations

import functools
import itertools
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

import numpy as np

from stereo_depth.errors import ParameterError

MAX_HISTORY = 8  # frames: RealSense's "k of the last 8"
GAP_PERIODS = 4.0  # a gap longer than this many frame periods (the shortest of the last intervals) restarts


@dataclass(frozen=True)
class TemporalSettings:
    """The filter's parameters (the `temporal_*` output options)."""

    alpha: float = 0.4
    delta: float = 2.0
    persistence: int = 4
    history: int = MAX_HISTORY
    motion_reset: float = 0.0  # share of changed pixels that restarts every pixel; 0: off

    def validate(self) -> TemporalSettings:
        if not 0.0 < self.alpha <= 1.0:
            msg = f"temporal_alpha {self.alpha} must be in (0, 1]"
            raise ParameterError(msg)
        if not 1 <= self.history <= MAX_HISTORY:
            msg = f"temporal_history {self.history} must be in [1, {MAX_HISTORY}]"
            raise ParameterError(msg)
        if not 1 <= self.persistence <= self.history:
            msg = f"temporal_persistence {self.persistence} must be in [1, temporal_history ({self.history})]"
            raise ParameterError(msg)
        return self


def compile_kernels() -> None:
    """Compile the kernels (or load them from numba's cache) for frames with and without confidence now,
    so that the first frame does not wait for them (a node would drop the frames arriving meanwhile)."""
    for confidence in (None, np.ones((2, 2), np.float32)):
        temporal = TemporalFilter()
        for stamp in (1, 2):
            temporal.apply(np.ones((2, 2), np.float32), confidence, stamp, None, TemporalSettings(motion_reset=0.5))


def lead_in_frames(history: int = MAX_HISTORY) -> int:
    """Frames before a shard's first that give it the state one pass has there: the output depends on
    the last `history` frames, and the restarts among them on the `history` stamps before each."""
    return 2 * history


class TemporalFilter:
    """The state of one stream of frames (one camera pair): feed it frames in stamp order."""

    def __init__(self) -> None:
        self._values: np.ndarray | None = None  # (history, pixels) float32; HOLE: invalid or before a restart
        self._weights: np.ndarray | None = None  # (history, pixels) float32 confidence; None: matcher gives none
        self._head = -1  # row of the newest frame
        self._frames = 0  # frames since the last restart
        self._stamps: deque[int] = deque(maxlen=MAX_HISTORY)  # the last stamps, across restarts
        self._calibration: Hashable = None

    def reset(self) -> None:
        """Forget every frame (the filter was switched off, or the stream starts anew)."""
        self._values = self._weights = None
        self._head, self._frames, self._calibration = -1, 0, None
        self._stamps.clear()

    def apply(
        self,
        disparity: np.ndarray,
        confidence: np.ndarray | None,
        stamp_ns: int,
        calibration: Hashable,
        settings: TemporalSettings,
    ) -> np.ndarray:
        """This frame's filtered disparity (a new float32 array, NaN invalid); `disparity` is not changed."""
        kernels = _kernels()
        pixels, history = disparity.size, settings.history
        if (
            self._values is None
            or self._values.shape != (history, pixels)
            or calibration != self._calibration
            or (confidence is None) != (self._weights is None)
        ):
            self._values = np.full((history, pixels), HOLE, np.float32)
            self._weights = None if confidence is None else np.zeros((history, pixels), np.float32)
            self._head, self._frames = -1, 0
        previous, self._head = self._head, (self._head + 1) % history
        both, changed = kernels["store"](
            disparity.reshape(-1),
            None if confidence is None else confidence.reshape(-1),
            self._values[self._head],
            None if self._weights is None else self._weights[self._head],
            self._values[previous] if self._frames and settings.motion_reset > 0 else None,  # the motion test's
            np.float32(settings.delta),
        )
        moved = settings.motion_reset > 0 and both > 0 and changed > settings.motion_reset * both
        if self._frames == 0 or moved or self._stamp_breaks(stamp_ns):
            self._values[np.arange(history) != self._head] = HOLE
            self._frames = 0
        self._stamps.append(stamp_ns)
        self._calibration = calibration
        self._frames += 1
        slots = (self._head - np.arange(min(self._frames, history))) % history
        out = np.empty(pixels, np.float32)
        kernels["filter"](
            self._values,
            self._weights,
            slots,
            np.float32(settings.alpha),
            np.float32(settings.delta),
            np.float32(settings.persistence),
            out,
        )
        return out.reshape(disparity.shape)

    def _stamp_breaks(self, stamp_ns: int) -> bool:
        """The stamp went back, or more than GAP_PERIODS frame periods passed (the period: the shortest
        interval among the last stamps, so frames a busy node dropped do not stretch it)."""
        if not self._stamps:
            return False
        last = self._stamps[-1]
        if stamp_ns <= last:
            return True
        stamps = list(self._stamps)
        intervals = [b - a for a, b in itertools.pairwise(stamps) if b > a]
        return bool(intervals) and stamp_ns - last > GAP_PERIODS * min(intervals)


# ----------------------------------------------------------------------------------------------- kernels
# Invalid pixels are HOLE in the history, not NaN, so "agrees with" is one branch-free comparison. No
# fastmath: its contractions (FMA) differ between a vector loop and its scalar remainder, so a pixel's
# result would depend on where its row starts in memory, and live and offline would differ in the last bit.

HOLE = np.float32(-1e9)
BRIDGED_FRAMES = 2  # a pixel invalid in this many latest frames still shows its last value (then: a trail)
BLOCK = 512  # pixels per block: the block's accumulators stay in L1 while the frames stream past


def _store(
    disparity: np.ndarray,
    confidence: np.ndarray | None,
    values: np.ndarray,
    weights: np.ndarray | None,
    previous: np.ndarray | None,
    delta: np.float32,
) -> tuple[int, int]:
    """This frame into its history rows (NaN -> HOLE; the confidence, when there is one); returns (pixels valid in this
    and the previous frame, those of them that moved by more than `delta`) for the motion test."""
    both = 0
    changed = 0
    for p in range(disparity.size):
        value = disparity[p]
        valid = value == value
        values[p] = value if valid else HOLE
        if weights is not None and confidence is not None:
            weights[p] = confidence[p]
        if previous is not None and valid and previous[p] != HOLE:
            both += 1
            changed += abs(value - previous[p]) > delta
    return both, changed


def _filter_pixels(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    alpha: np.float32,
    delta: np.float32,
    persistence: np.float32,
    out: np.ndarray,
) -> None:
    """Per pixel: the newest valid value of the last BRIDGED_FRAMES + 1 frames (a), the previous frame's
    when a is this frame's (b), and over the history how many frames agree with each (support) or hold
    another valid value (conflict). Output: a's weighted average when a is supported (support >=
    persistence, support >= conflict), else b's when b is supported and differs from a (a new value seen
    once: an outlier, or the first frame of a change), else invalid.

    `slots`: the history's rows, newest first, as many as there are frames since the restart. Block by
    block, frame by frame, without branches, so that the inner loops vectorise; numba compiles the
    `weights is None` case (no confidence) without the weights."""
    frames = slots.size
    cand_a = np.empty(BLOCK, np.float32)
    cand_b = np.empty(BLOCK, np.float32)
    # a: support, conflict, weights, weighted values; b: support, conflict, weights, weighted values
    acc = np.empty((8, BLOCK), np.float32)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    nan = np.float32(np.nan)
    no_weights = np.ones(BLOCK, np.float32)
    for start in range(0, out.size, BLOCK):
        n = min(BLOCK, out.size - start)
        stop = start + n
        cand_a[:n] = HOLE
        cand_b[:n] = HOLE
        acc[:, :n] = zero
        for age in range(min(BRIDGED_FRAMES + 1, frames)):
            row = values[slots[age], start:stop]
            for i in range(n):
                cand_a[i] = row[i] if cand_a[i] == HOLE else cand_a[i]
        if frames > 1:  # b: the previous frame's value, when a is this frame's
            newest, previous = values[slots[0], start:stop], values[slots[1], start:stop]
            for i in range(n):
                cand_b[i] = previous[i] if newest[i] != HOLE else HOLE
        decay = alpha
        for age in range(frames):
            row = values[slots[age], start:stop]
            row_weights = no_weights if weights is None else weights[slots[age], start:stop]
            for i in range(n):
                value = row[i]
                valid = one if value != HOLE else zero
                in_a = one if abs(value - cand_a[i]) <= delta else zero  # HOLE never agrees with a value
                in_b = one if abs(value - cand_b[i]) <= delta else zero
                weight = decay * row_weights[i]
                acc[0, i] += in_a
                acc[1, i] += valid - in_a
                acc[2, i] += weight * in_a
                acc[3, i] += weight * in_a * value
                acc[4, i] += in_b
                acc[5, i] += valid - in_b
                acc[6, i] += weight * in_b
                acc[7, i] += weight * in_b * value
            decay *= one - alpha
        for i in range(n):  # both candidates' results, then a choice: no branch to mispredict
            a, b = cand_a[i], cand_b[i]
            use_a = (a != HOLE) & (acc[0, i] >= persistence) & (acc[1, i] <= acc[0, i])
            use_b = (b != HOLE) & (abs(a - b) > delta) & (acc[4, i] >= persistence) & (acc[5, i] <= acc[4, i])
            mean_a = acc[3, i] / acc[2, i] if acc[2, i] > zero else a
            mean_b = acc[7, i] / acc[6, i] if acc[6, i] > zero else b
            out[start + i] = mean_a if use_a else (mean_b if use_b else nan)


@functools.cache
def _kernels() -> dict[str, Callable[..., Any]]:
    """numba-compiled kernels, built (or loaded from numba's cache) on first use."""
    import numba

    return {
        "store": numba.njit(cache=True, nogil=True)(_store),
        "filter": numba.njit(cache=True, nogil=True)(_filter_pixels),
    }
