"""Temporal filter: per-pixel disparity over the last few frames, so a match seen once never becomes a point.

Navigation stacks mark what a depth frame shows; a pixel that is wrong in one frame is a ghost obstacle.
For each pixel the filter keeps its disparity in the last `history` frames (1/16 px, HOLE where
invalid). The values of the CANDIDATE_FRAMES (3) newest frames are its candidates; the remembered frames
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
        self._values: np.ndarray | None = None  # (history, pixels) 1/16 px; HOLE: invalid or before a restart
        self._weights: np.ndarray | None = None  # (history, pixels) confidence 0..255; None: matcher gives none
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
            self._values = np.full((history, pixels), HOLE, np.int16)
            self._weights = None if confidence is None else np.zeros((history, pixels), np.uint8)
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
# a quarter of float32's bytes, which is what the filter's time goes on (it streams the whole history
# once per frame). No fastmath: its contractions (FMA) differ between a vector loop and its scalar
# remainder, so a pixel's result would depend on where its row starts in memory, and live and offline
# would differ in the last bit.

SUBPIXELS = 16  # the history's and the output's step, 1/16 px: DisparityImage's delta_d, OpenCV's fixed point
HOLE = np.int16(-32768)
CONFIDENCE_LEVELS = 255
CANDIDATE_FRAMES = 3  # the values of this many newest frames are the candidates (then: a trail)
prange = range  # numba.prange once the kernels are compiled (_kernels)
BLOCK = 256  # pixels per block: the block's accumulators stay in L1 while the frames stream past


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


def _filter_pixels(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    alpha: np.float32,
    delta: np.float32,
    persistence: np.float32,
    out: np.ndarray,
    parts: int,
) -> None:
    """Per pixel, each of the values of the CANDIDATE_FRAMES newest frames is a candidate; over the
    history, the frames within `delta` of it support it, the other valid frames conflict with it. A
    candidate passes with support >= persistence and support >= conflict; of those that pass, the one
    with the most support (confidence-weighted when the matcher gives one) is output, the newer on a
    tie: its weighted average (candidate + the average offset of its supporters, so equal values
    average to themselves exactly), rounded to 1/16 px. None passes: invalid.

    `slots`: the history's rows, newest first, as many as there are frames since the restart. Block by
    block, frame by frame, without branches, so that the inner loops vectorise; numba compiles the
    `weights is None` case (no confidence) without the weights. The pixels are cut into `parts` runs of
    whole blocks, one per thread; each pixel's result is the same whatever the count."""
    frames = slots.size
    candidates = min(CANDIDATE_FRAMES, frames)
    blocks = -(-out.size // BLOCK)
    for part in prange(parts):
        _filter_blocks(
            values,
            weights,
            slots,
            alpha,
            delta,
            persistence,
            out,
            frames,
            candidates,
            part * blocks // parts * BLOCK,
            min((part + 1) * blocks // parts * BLOCK, out.size),
        )


def _filter_blocks(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    alpha: np.float32,
    delta: np.float32,
    persistence: np.float32,
    out: np.ndarray,
    frames: int,
    candidates: int,
    first: int,
    last: int,
) -> None:
    """`_filter_pixels` on the pixels first..last (whole blocks), with scratch of its own."""
    cand = np.empty((CANDIDATE_FRAMES, BLOCK), np.float32)
    # per candidate: support, confidence-weighted support, weight, weighted offset
    support = np.empty((CANDIDATE_FRAMES, BLOCK), np.float32)
    trust = np.empty((CANDIDATE_FRAMES, BLOCK), np.float32)
    weight = np.empty((CANDIDATE_FRAMES, BLOCK), np.float32)
    offsets = np.empty((CANDIDATE_FRAMES, BLOCK), np.float32)
    valid = np.empty(BLOCK, np.float32)  # frames with a value
    value = np.empty(BLOCK, np.float32)  # one frame's values
    confidence = np.empty(BLOCK, np.float32)  # one frame's confidences, and times its decay
    weighted = np.empty(BLOCK, np.float32)
    best = np.empty(BLOCK, np.float32)  # the chosen candidate's trust, and its value
    result = np.empty(BLOCK, np.float32)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    hole = np.float32(HOLE)
    limit = delta * np.float32(SUBPIXELS)
    step = np.float32(1.0 / SUBPIXELS)
    nan = np.float32(np.nan)
    for start in range(first, last, BLOCK):
        n = min(BLOCK, last - start)
        stop = start + n
        for c in range(CANDIDATE_FRAMES):
            row = values[slots[min(c, frames - 1)], start:stop]
            for i in range(n):
                cand[c, i] = np.float32(row[i]) if c < candidates else hole
                support[c, i] = trust[c, i] = weight[c, i] = offsets[c, i] = zero
        valid[:n] = zero
        decay = alpha
        for age in range(frames):
            row = values[slots[age], start:stop]
            for i in range(n):
                value[i] = np.float32(row[i])
                valid[i] += one if value[i] != hole else zero
            if weights is not None:
                confidences = weights[slots[age], start:stop]
                for i in range(n):
                    confidence[i] = np.float32(confidences[i])
                    weighted[i] = decay * confidence[i]
            for c in range(candidates):  # HOLE agrees with HOLE only; a HOLE candidate never passes
                cand_c, support_c, trust_c = cand[c], support[c], trust[c]
                weight_c, offsets_c = weight[c], offsets[c]
                if weights is None:
                    for i in range(n):
                        offset = value[i] - cand_c[i]
                        agree = decay if abs(offset) <= limit else zero
                        support_c[i] += one if abs(offset) <= limit else zero
                        weight_c[i] += agree
                        offsets_c[i] += agree * offset
                else:
                    for i in range(n):
                        offset = value[i] - cand_c[i]
                        agree = one if abs(offset) <= limit else zero
                        support_c[i] += agree
                        trust_c[i] += agree * confidence[i]
                        weight_c[i] += agree * weighted[i]
                        offsets_c[i] += agree * weighted[i] * offset
            decay *= one - alpha
        if weights is None:
            trust[:, :n] = support[:, :n]
        best[:n] = -one
        result[:n] = nan
        for c in range(candidates):  # each candidate's test, then a choice: no branch to mispredict
            cand_c, support_c, trust_c = cand[c], support[c], trust[c]
            weight_c, offsets_c = weight[c], offsets[c]
            for i in range(n):
                passes = (cand_c[i] != hole) & (support_c[i] >= persistence) & (valid[i] - support_c[i] <= support_c[i])
                mean = cand_c[i] + (offsets_c[i] / weight_c[i] if weight_c[i] > zero else zero)
                better = passes & (trust_c[i] > best[i])
                best[i] = trust_c[i] if better else best[i]
                result[i] = mean if better else result[i]
        for i in range(n):
            out[start + i] = np.rint(result[i]) * step  # NaN stays NaN


def _threads() -> int:
    """The numba threads given to work on this thread (core/threads.py `use_threads`: cpu_threads)."""
    import numba

    return int(numba.get_num_threads())


@functools.cache
def _kernels() -> dict[str, Callable[..., Any]]:
    """numba-compiled kernels, built (or loaded from numba's cache) on first use."""
    import numba

    module = globals()  # the parallel kernel calls the compiled block kernel, and numba's prange
    module["prange"] = numba.prange
    module["_filter_blocks"] = numba.njit(cache=True, nogil=True)(_filter_blocks)
    return {
        "store": numba.njit(cache=True, nogil=True, parallel=True)(_store),
        "filter": numba.njit(cache=True, nogil=True, parallel=True)(_filter_pixels),
    }
