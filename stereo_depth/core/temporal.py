"""Temporal filter: per-pixel disparity over the last few frames, so a match seen once never becomes a point.

Navigation stacks mark what a depth frame shows; a pixel that is wrong in one frame is a ghost obstacle.
For each pixel the filter keeps its disparity in the last `history` frames (1/16 px, HOLE where
invalid). The values of the three newest frames are its candidates; the remembered frames
within `delta` px of one support it, the other valid ones conflict with it. A candidate passes when at
least `persistence` frames support it (RealSense's "valid in k of the last n": a wrong match seen once
has no support) and no more conflict than support (a pixel that flips between two values is not
output); of those that pass, the one with the most support is output (confidence-weighted when the
matcher gives one, census_sgm), the newer on a tie; none passes: invalid. Three candidates, not the
newest value alone: in textureless parts the noise spreads wider than `delta`, and the newest value at
the edge of the spread would blank a pixel that a value of the frames before still describes. Older
values never stand in, so an object that left leaves a trail of at most 2 frames, and a hole of up to
2 frames keeps the last value.

The value is an exponential average of the supporting frames (`alpha`, the newest frame's weight;
older frames' weights fall by 1 - alpha per frame; each also weighted by the matcher's confidence),
taken as the candidate plus its supporters' average offset, so equal values average to themselves
exactly, and rounded to 1/16 px, the step the history holds and DisparityImage announces (delta_d).

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

    alpha: float = 0.2
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
        # (MAX_HISTORY, pixels): rows 0..history-1 a ring of frames, the rest HOLE (the kernel reads 8 rows)
        self._values: np.ndarray | None = None  # 1/16 px; HOLE: invalid, before a restart, or beyond history
        self._weights: np.ndarray | None = None  # confidence 0..255; None: the matcher gives none
        self._history = 0
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
            or self._values.shape[1] != pixels
            or history != self._history
            or calibration != self._calibration
            or (confidence is None) != (self._weights is None)
        ):
            self._values = np.full((MAX_HISTORY, pixels), HOLE, np.int16)
            self._weights = None if confidence is None else np.zeros((MAX_HISTORY, pixels), np.uint8)
            self._head, self._frames, self._history = -1, 0, history
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
            self._values[np.arange(MAX_HISTORY) != self._head] = HOLE
            self._frames = 0
        self._stamps.append(stamp_ns)
        self._calibration = calibration
        self._frames += 1
        ages = np.arange(MAX_HISTORY)
        slots = np.where(ages < history, (self._head - ages) % history, ages)  # newest first; then HOLE rows
        out = np.empty(pixels, np.float32)
        kernels["filter"](
            self._values,
            self._weights,
            slots,
            _decays(settings.alpha),
            np.float32(settings.delta),
            np.float32(settings.persistence),
            out,
            _threads(),
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
# The history holds 1/16 px fixed point (int16, HOLE where invalid) and the confidence as 0..255 (uint8):
# a quarter of float32's bytes to stream through per frame. Always MAX_HISTORY rows, those beyond
# `history` HOLE, so the kernel's frame loop is written out eight times and each pixel's sums stay in
# registers (a loop over the frames inside the pixel loop would keep it from vectorising). No fastmath:
# its contractions (FMA) differ between a vector loop and its scalar remainder, so a pixel's result would
# depend on where its row starts in memory, and live and offline would differ in the last bit.

SUBPIXELS = 16  # the history's and the output's step, 1/16 px: DisparityImage's delta_d, OpenCV's fixed point
HOLE = np.int16(-32768)
CONFIDENCE_LEVELS = 255
prange = range  # numba.prange once the kernels are compiled (_kernels)


def _store(
    disparity: np.ndarray,
    confidence: np.ndarray | None,
    values: np.ndarray,
    weights: np.ndarray | None,
    previous: np.ndarray | None,
    delta: np.float32,
) -> tuple[int, int]:
    """This frame into its history rows (1/16 px, NaN -> HOLE; the confidence, when there is one);
    returns (pixels valid in this and the previous frame, those of them that moved by more than
    `delta` px) for the motion test."""
    both = 0
    changed = 0
    limit = delta * SUBPIXELS
    for p in prange(disparity.size):
        value = disparity[p]
        fixed = np.int16(np.rint(value * SUBPIXELS)) if value == value else HOLE
        values[p] = fixed
        if weights is not None and confidence is not None:
            weights[p] = np.uint8(np.rint(min(max(confidence[p], 0.0), 1.0) * CONFIDENCE_LEVELS))
        if previous is not None and fixed != HOLE and previous[p] != HOLE:
            both += 1
            changed += int(abs(np.int32(fixed) - np.int32(previous[p])) > limit)
    return both, changed


def _decays(alpha: float) -> np.ndarray:
    """Each age's weight in the average, newest first: alpha, then falling by 1 - alpha a frame."""
    decays = np.empty(MAX_HISTORY, np.float32)
    decay, keep = np.float32(alpha), np.float32(1.0) - np.float32(alpha)
    for age in range(MAX_HISTORY):
        decays[age] = decay
        decay *= keep
    return decays


def _filter_pixels(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    decays: np.ndarray,
    delta: np.float32,
    persistence: np.float32,
    out: np.ndarray,
    parts: int,
) -> None:
    """Per pixel, each of the values of the three newest frames is a candidate; over the history, the
    frames within `delta` of it support it, the other valid frames conflict with it. A candidate passes
    with support >= persistence and support >= conflict; of those that pass, the one with the most
    support (confidence-weighted when the matcher gives one) is output, the newer on a tie: its weighted
    average (candidate + the average offset of its supporters, so equal values average to themselves
    exactly), rounded to 1/16 px. None passes: invalid.

    `slots`: the MAX_HISTORY rows, newest first (rows of frames before a restart or beyond the history
    are HOLE: they support nothing). The pixels are cut into `parts` runs, one per thread; each pixel's
    result is the same whatever the count."""
    for part in prange(parts):
        _filter_range(
            values,
            weights,
            slots,
            decays,
            delta,
            persistence,
            out,
            part * out.size // parts,
            (part + 1) * out.size // parts,
        )


def _filter_range(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    decays: np.ndarray,
    delta: np.float32,
    persistence: np.float32,
    out: np.ndarray,
    first: int,
    last: int,
) -> None:
    """`_filter_pixels` on the pixels first..last-1. The eight frames are written out one by one
    (`_add_frame`, inlined) on row views indexed from 0, so that each pixel's sums stay in registers and
    the pixel loop vectorises; numba compiles the `weights is None` case (no confidence) without the
    weights."""
    one = np.float32(1.0)
    limit = delta * np.float32(SUBPIXELS)
    v0, v1, v2, v3, v4, v5, v6, v7 = _frame_rows(values, slots, first, last)
    d0, d1, d2, d3, d4, d5, d6, d7 = (
        decays[0],
        decays[1],
        decays[2],
        decays[3],
        decays[4],
        decays[5],
        decays[6],
        decays[7],
    )
    result = out[first:last]
    if weights is None:
        for i in range(last - first):
            a, b, c = np.float32(v0[i]), np.float32(v1[i]), np.float32(v2[i])
            sums = _add_frame(_NO_SUMS, v0[i], one, d0, a, b, c, limit)
            sums = _add_frame(sums, v1[i], one, d1, a, b, c, limit)
            sums = _add_frame(sums, v2[i], one, d2, a, b, c, limit)
            sums = _add_frame(sums, v3[i], one, d3, a, b, c, limit)
            sums = _add_frame(sums, v4[i], one, d4, a, b, c, limit)
            sums = _add_frame(sums, v5[i], one, d5, a, b, c, limit)
            sums = _add_frame(sums, v6[i], one, d6, a, b, c, limit)
            sums = _add_frame(sums, v7[i], one, d7, a, b, c, limit)
            result[i] = _chosen(sums, a, b, c, persistence)
    else:
        c0, c1, c2, c3, c4, c5, c6, c7 = _frame_rows(weights, slots, first, last)
        for i in range(last - first):
            a, b, c = np.float32(v0[i]), np.float32(v1[i]), np.float32(v2[i])
            w = np.float32(c0[i])
            sums = _add_frame(_NO_SUMS, v0[i], w, d0 * w, a, b, c, limit)
            w = np.float32(c1[i])
            sums = _add_frame(sums, v1[i], w, d1 * w, a, b, c, limit)
            w = np.float32(c2[i])
            sums = _add_frame(sums, v2[i], w, d2 * w, a, b, c, limit)
            w = np.float32(c3[i])
            sums = _add_frame(sums, v3[i], w, d3 * w, a, b, c, limit)
            w = np.float32(c4[i])
            sums = _add_frame(sums, v4[i], w, d4 * w, a, b, c, limit)
            w = np.float32(c5[i])
            sums = _add_frame(sums, v5[i], w, d5 * w, a, b, c, limit)
            w = np.float32(c6[i])
            sums = _add_frame(sums, v6[i], w, d6 * w, a, b, c, limit)
            w = np.float32(c7[i])
            sums = _add_frame(sums, v7[i], w, d7 * w, a, b, c, limit)
            result[i] = _chosen(sums, a, b, c, persistence)


def _frame_rows(
    frames: np.ndarray, slots: np.ndarray, first: int, last: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The eight stored frames' pixels first..last-1, newest first, as views indexed from 0."""
    return (
        frames[slots[0], first:last],
        frames[slots[1], first:last],
        frames[slots[2], first:last],
        frames[slots[3], first:last],
        frames[slots[4], first:last],
        frames[slots[5], first:last],
        frames[slots[6], first:last],
        frames[slots[7], first:last],
    )


_NO_SUMS = (np.float32(0.0),) * 13  # per candidate a, b, c: support, trust, weight, offset; then valid frames


def _chosen(
    sums: tuple[np.float32, ...], a: np.float32, b: np.float32, c: np.float32, persistence: np.float32
) -> np.float32:
    """Each candidate's test, then a choice, newest first, without a branch to mispredict: the chosen
    candidate's average rounded to 1/16 px, or NaN."""
    zero = np.float32(0.0)
    hole = np.float32(HOLE)
    support_a, trust_a, weight_a, offset_a, support_b, trust_b, weight_b, offset_b = sums[:8]
    support_c, trust_c, weight_c, offset_c, valid = sums[8:]
    mean_a = a + (offset_a / weight_a if weight_a > zero else zero)
    mean_b = b + (offset_b / weight_b if weight_b > zero else zero)
    mean_c = c + (offset_c / weight_c if weight_c > zero else zero)
    pass_a = (a != hole) & (support_a >= persistence) & (valid - support_a <= support_a)
    best = trust_a if pass_a else np.float32(-1.0)
    mean = mean_a if pass_a else np.float32(np.nan)
    pass_b = (b != hole) & (support_b >= persistence) & (valid - support_b <= support_b) & (trust_b > best)
    best = trust_b if pass_b else best
    mean = mean_b if pass_b else mean
    pass_c = (c != hole) & (support_c >= persistence) & (valid - support_c <= support_c) & (trust_c > best)
    mean = mean_c if pass_c else mean
    return np.float32(np.rint(mean) * np.float32(1.0 / SUBPIXELS))  # NaN stays NaN


def _agree(
    support: np.float32,
    trust: np.float32,
    weight_sum: np.float32,
    offset: np.float32,
    v: np.float32,
    candidate: np.float32,
    confidence: np.float32,
    weight: np.float32,
    limit: np.float32,
) -> tuple[np.float32, np.float32, np.float32, np.float32]:
    """One candidate's sums after one frame's value `v`: support (frames within `limit`, 1/16 px),
    confidence-weighted support, weight and weighted offset."""
    d = v - candidate
    agree = np.float32(1.0) if abs(d) <= limit else np.float32(0.0)
    return support + agree, trust + agree * confidence, weight_sum + agree * weight, offset + agree * weight * d


def _add_frame(
    sums: tuple[np.float32, ...],
    value: np.int16,
    confidence: np.float32,
    weight: np.float32,
    a: np.float32,
    b: np.float32,
    c: np.float32,
    limit: np.float32,
) -> tuple[np.float32, ...]:
    """One frame's value into a pixel's sums: `_agree` for candidates a, b and c, then the valid frames.
    A HOLE agrees with a HOLE only, and a HOLE candidate never passes."""
    v = np.float32(value)
    valid = sums[12] + (np.float32(1.0) if value != HOLE else np.float32(0.0))
    return (
        *_agree(sums[0], sums[1], sums[2], sums[3], v, a, confidence, weight, limit),
        *_agree(sums[4], sums[5], sums[6], sums[7], v, b, confidence, weight, limit),
        *_agree(sums[8], sums[9], sums[10], sums[11], v, c, confidence, weight, limit),
        valid,
    )


def _threads() -> int:
    """The numba threads given to work on this thread (core/threads.py `use_threads`: cpu_threads)."""
    import numba

    return int(numba.get_num_threads())


@functools.cache
def _kernels() -> dict[str, Callable[..., Any]]:
    """numba-compiled kernels, built (or loaded from numba's cache) on first use."""
    import numba

    module = globals()  # the parallel kernel calls the compiled ones below it, and numba's prange
    module["prange"] = numba.prange
    module["_agree"] = numba.njit(cache=True, inline="always")(_agree)
    module["_add_frame"] = numba.njit(cache=True, inline="always")(_add_frame)
    module["_chosen"] = numba.njit(cache=True, inline="always")(_chosen)
    module["_frame_rows"] = numba.njit(cache=True, inline="always")(_frame_rows)
    module["_filter_range"] = numba.njit(cache=True, nogil=True)(_filter_range)
    return {
        "store": numba.njit(cache=True, nogil=True, parallel=True)(_store),
        "filter": numba.njit(cache=True, nogil=True, parallel=True)(_filter_pixels),
    }
