"""Temporal filter: per-pixel disparity over the last frames, so a match seen once, or a wrong one that
comes back now and then, never becomes a point.

Navigation stacks mark what a depth frame shows; a pixel that is wrong in one frame is a ghost obstacle.
For each pixel the filter keeps its disparity in the last `LONG_RUN` frames (1/16 px, HOLE where invalid)
and the matcher's confidence (1 for a matcher without one). The values of the three newest frames are
its candidates; a remembered frame within `delta` px of one supports it, another valid one conflicts
with it, each vote weighed by that frame's confidence. A candidate passes when

- persistence: at least `persistence` of the last `history` frames support it (RealSense's "valid in k
  of the last n": a wrong match seen once has no support);
- the disagree rule: over those frames, its confidence-weighted support is no less than its weighted
  conflict (a pixel that flips between two values is not output);
- presence: the pixel was valid in at least `presence` of the frames that saw it, over the last
  `LONG_RUN` frames and, while the view holds still, the frames before them, up to `PRESENCE_RUN` in
  all (a wrong match in a place that is mostly a hole comes back in runs of several frames on a real
  sensor, and persistence, or a share over the last 16 frames, would pass each run; over a still
  view's few seconds the share is steady, so a pixel is output most of the time or not at all);
- the long-run rule, over the last `LONG_RUN` frames: when its supporting frames alternate with
  conflicting ones (the pixel keeps switching surfaces, or the wrong value was seen before), its
  weighted support over the long run is no less than the conflict. A clean change (every conflicting
  frame older than every supporting one: an object arrived) is exempt, so new surfaces appear as soon
  as persistence allows.

Of those that pass, the one with the most (weighted) support is output, the newer on a tie; none passes:
invalid. Three candidates, not the newest value alone: in textureless parts the noise spreads wider than
`delta`, and the newest value at the edge of the spread would blank a pixel that a value of the frames
before still describes. Older values never stand in, so an object that left leaves a trail of at most 2
frames, and a hole of up to 2 frames keeps the last value.

The value is an exponential average of the supporting frames of the last `history` (`alpha`, the newest
frame's weight; older frames' weights fall by 1 - alpha per frame; each also weighted by its confidence),
taken as the candidate plus its supporters' average offset, so equal values average to themselves
exactly, and rounded to 1/16 px, the step the history holds and DisparityImage announces (delta_d).

The output is a function of the last `PRESENCE_RUN` frames alone (no recursion over the whole stream), so
a bag cut into shards gives bit-identical results once each shard is fed `lead_in_frames` frames before
its first.
Everything restarts (the history is emptied) when the stamp goes back (a looping bag, a restarted
driver), when more than `GAP_PERIODS` frame periods pass without a frame, when the calibration or the
image size changes, and, with `motion_reset`, when more than that share of the pixels valid in both
frames changed by more than `delta` since the previous frame (the camera jumped: everything changed).
Given the frame's rectified left image, it also restarts when the view shifted by more than `ego_motion`
px since the previous frame (the median over tiles of their phase correlation, so an object crossing a
still view does not count): the camera turns or moves, and the history no longer lies under the same
pixels. It then stands aside: frames pass unfiltered until `persistence` frames of a still view refill
the history, so that without odometry the filter never makes a moving camera's depth worse.

With odometry (`CameraMotion`: the rectified left camera's pose at each frame), the history moves with
the camera instead: before the vote, each remembered frame is projected into this frame's view through
its own depth and the relative pose between the two frames (a forward warp: the nearest point wins a
pixel, one-pixel cracks are closed), so a still surface agrees with itself while the robot drives or
turns, and the image test stands down while the odometry explains the motion; presence then counts the
frames since the history last moved only. Each frame is moved from
where it was taken, never from a moved copy, so the error does not build up. A frame without a pose
(its odometry late) is voted on unmoved, with the image test; one whose odometry stopped or jumped
restarts everything.
ROS-free; the kernels are numba-compiled on first use (census_sgm's dependency), then cached.
"""

from __future__ import annotations

import functools
import itertools
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any, NamedTuple

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.errors import ParameterError

MAX_HISTORY = 8  # frames: RealSense's "k of the last 8"
LONG_RUN = 16  # frames the long-run rules look back over
PRESENCE_RUN = 128  # frames presence looks back over while the view holds still
GAP_PERIODS = 4.0  # a gap longer than this many frame periods (the shortest of the last intervals) restarts
PERIOD_STAMPS = 4  # the stamps whose intervals give the frame period
VIEW_SCALE = 4  # the ego-motion test compares the views at a quarter of their size
VIEW_TILES = 3  # in 3 x 3 tiles
NEVER_SEEN = 2 * LONG_RUN  # the history's row that stays UNSEEN: what the unmoved old frames vote with
STILL_PX = 0.25  # a remembered frame whose move would shift no pixel further stays where it is


@dataclass(frozen=True)
class TemporalSettings:
    """The filter's parameters (the `temporal_*` output options)."""

    alpha: float = 0.2
    delta: float = 2.0
    persistence: int = 4
    history: int = MAX_HISTORY
    motion_reset: float = 0.0  # share of changed pixels that restarts every pixel; 0: off
    presence: float = 0.4  # share of the frames a pixel must be valid in (up to PRESENCE_RUN while still)
    ego_motion: float = 0.5  # px the view may shift between frames before the filter stands aside; 0: off

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
        if not 0.0 <= self.presence <= 1.0:
            msg = f"temporal_presence {self.presence} must be in [0, 1]"
            raise ParameterError(msg)
        if self.ego_motion < 0.0:
            msg = f"temporal_ego_motion {self.ego_motion} must be >= 0"
            raise ParameterError(msg)
        return self


class Projection(NamedTuple):
    """The rectified left camera at the disparity's size: what turns a disparity into a point and back."""

    fx: float
    fy: float
    cx: float
    cy: float
    fb: float  # fx * baseline, px m: depth = fb / (disparity - offset)
    offset: float  # cx_left - cx_right, px

    @classmethod
    def of(cls, camera: StereoCamera) -> Projection:
        return cls(
            camera.fx, camera.fy, camera.cx_left, camera.cy, camera.fx * camera.baseline, camera.disparity_offset
        )


class CameraMotion(NamedTuple):
    """Where a frame was taken: the rectified left camera's pose in the odometry frame (4x4 float64, the
    camera's points to the odometry frame's; None: not known for this frame) and its projection; `forget`:
    the odometry stopped or jumped, so the history no longer lines up."""

    pose: np.ndarray | None
    projection: Projection
    forget: bool = False


def compile_kernels() -> None:
    """Compile the kernels (or load them from numba's cache) for frames with and without confidence now,
    so that the first frame does not wait for them (a node would drop the frames arriving meanwhile)."""
    for confidence in (None, True):
        temporal = TemporalFilter()
        projection = Projection(1.0, 1.0, 0.5, 0.5, 1.0, 0.0)
        for stamp in range(1, LONG_RUN + 3):
            pose = np.eye(4)
            pose[0, 3] = stamp  # moved once (the history's move runs), then unknown: presence's count runs
            temporal.apply(
                np.ones((3, 3), np.float32),
                None if confidence is None else np.ones((3, 3), np.float32),
                stamp,
                None,
                TemporalSettings(motion_reset=0.5),
                motion=CameraMotion(pose if stamp <= 2 else None, projection),
            )


def _view_shift(previous: np.ndarray, current: np.ndarray) -> float:
    """How far the view moved, px at this size: the median over VIEW_TILES x VIEW_TILES tiles of each
    tile's shift (phase correlation), so that an object moving across a still view does not count."""
    height, width = _dft_size(current.shape[0] // VIEW_TILES), _dft_size(current.shape[1] // VIEW_TILES)
    window = _hanning((height, width))
    shifts = []
    for row in range(VIEW_TILES):
        for col in range(VIEW_TILES):
            tile = np.s_[row * height : (row + 1) * height, col * width : (col + 1) * width]
            (dx, dy), _ = cv2.phaseCorrelate(previous[tile].copy(), current[tile].copy(), window)  # it writes to them
            shifts.append(np.hypot(dx, dy))
    return float(np.median(shifts))


def _dft_size(size: int) -> int:
    """The largest power of two up to `size`: OpenCV's phase correlation reports a still view as shifted by
    half a pixel at some other sizes (13-15, 25-27, 41-45 px, ...)."""
    return 1 << max(0, size.bit_length() - 1)


@functools.cache
def _hanning(shape: tuple[int, int]) -> np.ndarray:
    return cv2.createHanningWindow((shape[1], shape[0]), cv2.CV_32F)


def _largest_shift(relative: np.ndarray, projection: Projection, shape: tuple[int, ...], nearest: float) -> float:
    """A bound on how far, px, moving a frame by `relative` shifts its pixels: the turn at the image's
    corners, plus the translation seen at the frame's nearest point (its largest disparity `nearest`)."""
    angle = float(np.arccos(np.clip((np.trace(relative[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    corner = np.hypot(max(projection.cx, shape[-1] - projection.cx), max(projection.cy, shape[0] - projection.cy))
    focal = max(projection.fx, projection.fy)
    turn = focal * angle * (1.0 + (corner / focal) ** 2)
    inverse_depth = max(nearest - projection.offset, 0.0) / projection.fb if np.isfinite(nearest) else 0.0
    moved = focal * float(np.linalg.norm(relative[:3, 3])) * inverse_depth * (1.0 + corner / focal)
    return float(turn + moved)


def lead_in_frames() -> int:
    """Frames before a shard's first that give it the state one pass has there: the output depends on
    the last PRESENCE_RUN frames, and the restarts among them on the PERIOD_STAMPS stamps before each."""
    return PRESENCE_RUN + PERIOD_STAMPS


class TemporalFilter:
    """The state of one stream of frames (one camera pair): feed it frames in stamp order."""

    def __init__(self) -> None:
        # (2 * LONG_RUN + 1, pixels): a ring of the last frames, rows before the last restart UNSEEN; then, row
        # LONG_RUN + r, frame r moved into the newest frame's view (with odometry); last, NEVER_SEEN
        self._values: np.ndarray | None = None  # 1/16 px; HOLE: invalid; UNSEEN: before a restart, out of view
        self._weights: np.ndarray | None = None  # confidence 0..255; None: the matcher gives none
        self._poses: list[np.ndarray | None] = [None] * LONG_RUN  # per ring row: where its frame was taken
        self._nearest = np.zeros(LONG_RUN)  # per ring row: its largest disparity, px (how far its points move)
        self._head = -1  # row of the newest frame
        self._frames = 0  # frames since the last restart
        self._still = 0  # the newest frames in this view: since the last restart or the history's last move
        # presence beyond the ring: per pixel, of the frames of ages LONG_RUN.. in this view (up to
        # PRESENCE_RUN - LONG_RUN of them: `_older_frames`), those it was valid in; their validity, a bit a pixel
        self._older_valid = np.zeros(0, np.uint8)
        self._older_bits = np.zeros((0, 0), np.uint8)
        self._stamps: deque[int] = deque(maxlen=PERIOD_STAMPS)  # the last stamps, across restarts
        self._calibration: Hashable = None
        self._view: np.ndarray | None = None  # the last frame's view, small, for the ego-motion test
        self._standing_aside = False  # the view moved: frames pass unfiltered until the history is refilled

    def reset(self) -> None:
        """Forget every frame (the filter was switched off, or the stream starts anew)."""
        self._values = self._weights = self._view = None
        self._older_valid, self._older_bits = np.zeros(0, np.uint8), np.zeros((0, 0), np.uint8)
        self._poses = [None] * LONG_RUN
        self._head, self._frames, self._still, self._calibration = -1, 0, 0, None
        self._standing_aside = False
        self._stamps.clear()

    def apply(
        self,
        disparity: np.ndarray,
        confidence: np.ndarray | None,
        stamp_ns: int,
        calibration: Hashable,
        settings: TemporalSettings,
        *,
        view: np.ndarray | None = None,
        motion: CameraMotion | None = None,
    ) -> np.ndarray:
        """This frame's filtered disparity (a new float32 array, NaN invalid); `disparity` is not changed.
        `view`: the frame's rectified left image (grey), for the ego-motion test; None: no test.
        `motion`: where the frame was taken (odometry); None: no odometry."""
        kernels = _kernels()
        pose = None if motion is None else motion.pose
        pixels = disparity.size
        if (
            self._values is None
            or self._values.shape[1] != pixels
            or calibration != self._calibration
            or (confidence is None) != (self._weights is None)
        ):
            self._values = np.full((NEVER_SEEN + 1, pixels), UNSEEN, np.int16)
            self._weights = None if confidence is None else np.zeros((NEVER_SEEN + 1, pixels), np.uint8)
            self._older_valid = np.zeros(pixels, np.uint8)
            self._older_bits = np.zeros((PRESENCE_RUN - LONG_RUN, -(-pixels // 8)), np.uint8)
            self._head, self._frames, self._still = -1, 0, 0
        previous, self._head = self._head, (self._head + 1) % LONG_RUN
        explained = pose is not None and self._frames > 0 and self._poses[previous] is not None
        turned = self._view_moved(view, settings.ego_motion) and not explained  # odometry explains the shift
        ring = (self._head - np.arange(LONG_RUN)) % LONG_RUN  # the rows, newest first
        slots = ring
        if pose is not None and motion is not None and self._frames:
            slots = self._moved_history(ring, pose, motion.projection, disparity.shape, settings.delta)
        self._still = 1 if (slots != ring).any() else self._still + 1
        self._age_out()
        both, changed = kernels["store"](
            disparity.reshape(-1),
            None if confidence is None else confidence.reshape(-1),
            self._values[self._head],
            None if self._weights is None else self._weights[self._head],
            self._values[slots[1]] if self._frames and settings.motion_reset > 0 else None,  # the motion test's
            np.float32(settings.delta),
        )
        moved = settings.motion_reset > 0 and both > 0 and changed > settings.motion_reset * both
        forget = motion is not None and motion.forget
        if self._frames == 0 or moved or turned or forget or self._stamp_breaks(stamp_ns):
            self._values[ring[1:]] = UNSEEN
            slots = ring
            self._frames, self._still = 0, 1
        if self._still == 1:
            self._older_valid.fill(0)
        self._poses[self._head] = pose
        self._nearest[self._head] = np.fmax.reduce(disparity, axis=None) if pose is not None else 0.0
        self._standing_aside = turned or self._standing_aside
        self._stamps.append(stamp_ns)
        self._calibration = calibration
        self._frames += 1
        out = np.empty(pixels, np.float32)
        kernels["filter"](
            self._values,
            self._weights,
            slots,
            _decays(settings.alpha, settings.history),
            (np.arange(MAX_HISTORY) < settings.history).astype(np.float32),  # the short window
            np.float32(settings.delta),
            np.float32(settings.persistence),
            np.float32(settings.presence),
            self._older_valid,
            np.float32(self._older_frames()),
            out,
            _threads(),
        )
        if self._standing_aside and self._frames < settings.persistence:
            return disparity.astype(np.float32, copy=True)  # no worse than no filter while the view moves
        self._standing_aside = False
        return out.reshape(disparity.shape)

    def _age_out(self) -> None:
        """The frame about to leave the ring (age LONG_RUN) into the presence counts beyond it, when this
        view has held since it was taken; the oldest of those leaves once PRESENCE_RUN frames are counted."""
        assert self._values is not None
        if self._still <= LONG_RUN:
            return
        _kernels()["age_out"](
            self._values[self._head],
            self._older_valid,
            self._older_bits[self._still % (PRESENCE_RUN - LONG_RUN)],
            self._still > PRESENCE_RUN,
        )

    def _older_frames(self) -> int:
        """The frames of this view older than the ring that presence counts."""
        return min(max(self._still - LONG_RUN, 0), PRESENCE_RUN - LONG_RUN)

    def _moved_history(
        self, ring: np.ndarray, pose: np.ndarray, projection: Projection, shape: tuple[int, ...], delta: float
    ) -> np.ndarray:
        """The rows to vote with, newest first: each remembered frame whose pose differs from this frame's
        by more than STILL_PX moved into this view (in its row of the second half), the others as they
        are. While the camera moves, frames older than the short window (MAX_HISTORY) are not moved but
        left unseen: the long-run rules then look back over the short window only, at half the cost."""
        assert self._values is not None
        here = np.linalg.inv(pose)
        slots = ring.copy()
        sources, transforms = [], []
        for age in range(1, min(self._frames, LONG_RUN - 1) + 1):
            then = self._poses[ring[age]]
            if then is None:
                continue
            relative = here @ then  # the camera then, in this frame's camera
            if _largest_shift(relative, projection, shape, float(self._nearest[ring[age]])) <= STILL_PX:
                continue
            if age >= MAX_HISTORY:
                slots[age] = NEVER_SEEN
                continue
            slots[age] = LONG_RUN + ring[age]
            sources.append(ring[age])
            transforms.append(relative[:3])
        if sources:
            weights = self._weights if self._weights is not None else np.zeros((NEVER_SEEN + 1, 1), np.uint8)
            _kernels()["warp"](
                self._values,
                weights,
                self._weights is not None,
                np.array(sources, np.int64),
                np.array(transforms, np.float64),
                np.array(projection, np.float64),
                shape[-1],
                np.int32(round(delta * SUBPIXELS)),
            )
        return slots

    def _view_moved(self, view: np.ndarray | None, limit: float) -> bool:
        """Whether the view shifted by more than `limit` px since the last frame (the camera turned or
        moved: the history no longer lies under the same pixels); remembers this frame's view."""
        if view is None or limit <= 0.0:
            self._view = None
            return False
        small = cv2.resize(
            view, (view.shape[1] // VIEW_SCALE, view.shape[0] // VIEW_SCALE), interpolation=cv2.INTER_AREA
        )
        small = small.astype(np.float32)
        previous, self._view = self._view, small
        if previous is None or previous.shape != small.shape or self._frames == 0:
            return False
        return _view_shift(previous, small) * VIEW_SCALE > limit

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
# The history holds 1/16 px fixed point (int16: HOLE where invalid, UNSEEN where the pixel was not in the
# view: a frame before the last restart, or one moved from where it did not see this pixel) and the
# confidence as 0..255 (uint8):
# a quarter of float32's bytes to stream through per frame. Always LONG_RUN rows, those before a restart
# HOLE, so the kernel's frame loop is written out and each pixel's sums stay in registers (a loop over the
# frames inside the pixel loop would keep it from vectorising). No fastmath: its contractions (FMA) differ
# between a vector loop and its scalar remainder, so a pixel's result would depend on where its row starts
# in memory, and live and offline would differ in the last bit.

SUBPIXELS = 16  # the history's and the output's step, 1/16 px: DisparityImage's delta_d, OpenCV's fixed point
HOLE = np.int16(-32768)
UNSEEN = np.int16(-32767)  # every value above it is a disparity
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
        if previous is not None and fixed != HOLE and previous[p] > UNSEEN:
            both += 1
            changed += int(abs(np.int32(fixed) - np.int32(previous[p])) > limit)
    return both, changed


def _age_out(leaving: np.ndarray, counts: np.ndarray, bits: np.ndarray, full: bool) -> None:
    """A frame's validity (`leaving`, 1/16 px) into the per-pixel counts of valid frames, and into
    `bits` (a bit per pixel); `full`: the frame `bits` held leaves the counts first."""
    for byte in prange(bits.size):
        old = np.int32(bits[byte]) if full else np.int32(0)
        new = np.int32(0)
        for bit in range(8):
            p = byte * 8 + bit
            if p < leaving.size:
                valid = np.int32(leaving[p] > UNSEEN)
                new |= valid << bit
                counts[p] = np.uint8(np.int32(counts[p]) + valid - ((old >> bit) & 1))
        bits[byte] = np.uint8(new)


def _warp_rows(
    values: np.ndarray,
    weights: np.ndarray,
    weighted: bool,
    sources: np.ndarray,
    transforms: np.ndarray,
    projection: np.ndarray,
    width: int,
    limit: np.int32,
) -> None:
    """Each row of `sources` moved into the newest frame's view, into row LONG_RUN + its own (and its
    confidence, when `weighted`): `transforms[k]` (3x4) maps the points of frame k's camera to this one's;
    `projection`: fx, fy, cx, cy, fb, offset. One thread a row, so the nearest point wins a pixel
    whatever the threads."""
    for k in prange(sources.size):
        row = sources[k]
        _warp_row(
            values[row],
            values[LONG_RUN + row],
            weights[row] if weighted else weights[0],
            weights[LONG_RUN + row] if weighted else weights[0],
            weighted,
            transforms[k],
            projection,
            width,
            limit,
        )


def _warp_row(
    source: np.ndarray,
    target: np.ndarray,
    source_weights: np.ndarray,
    target_weights: np.ndarray,
    weighted: bool,
    transform: np.ndarray,
    projection: np.ndarray,
    width: int,
    limit: np.int32,
) -> None:
    """One frame's disparities (1/16 px) forward-warped: each valid pixel's point, from its disparity,
    moved by `transform` and projected; where several land on a pixel the nearest (largest disparity)
    wins; then the cracks a forward warp leaves where the view stretches are closed. Per image row, the
    projection first (branch-free, so it vectorises), then the writes."""
    f32 = np.float32
    fx, fy, cx, cy = f32(projection[0]), f32(projection[1]), f32(projection[2]), f32(projection[3])
    inverse_fb, offset = f32(1.0 / projection[4]), f32(projection[5])
    inverse_fx = f32(1.0 / projection[0])
    r = transform.astype(np.float32)
    height = source.size // width
    target[:] = UNSEEN
    fallback = _mean_disparity(source) * f32(1.0 / SUBPIXELS)  # where the frame's holes were: its mean depth
    places = np.empty(width, np.int32)
    moved = np.empty(width, np.int16)
    top, right, bottom = f32(0.0), f32(width), f32(height)
    for v in range(height):
        yn = (f32(v) - cy) / fy
        row_x, row_y, row_z = r[0, 1] * yn + r[0, 2], r[1, 1] * yn + r[1, 2], r[2, 1] * yn + r[2, 2]
        start = v * width
        for u in range(width):
            value = source[start + u]
            valid = value > UNSEEN
            d = (f32(value) * f32(1.0 / SUBPIXELS) if valid else fallback) - offset
            s = d * inverse_fb  # inverse depth, 1/m: the point is (xn, yn, 1) / s
            xn = (f32(u) - cx) * inverse_fx
            x = r[0, 0] * xn + row_x + r[0, 3] * s
            y = r[1, 0] * xn + row_y + r[1, 3] * s
            z = r[2, 0] * xn + row_z + r[2, 3] * s
            near = f32(1.0) / z
            column = fx * x * near + cx + f32(0.5)
            line = fy * y * near + cy + f32(0.5)
            fixed = (d * near + offset) * f32(SUBPIXELS) + f32(0.5)
            ok = (
                (d > f32(0.0))
                & (z > f32(1e-6))
                & (column >= top)
                & (column < right)
                & (line >= top)
                & (line < bottom)
                & (fixed < f32(32767.0))
            )
            column = column if ok else top
            line = line if ok else top
            places[u] = np.int32(line) * np.int32(width) + np.int32(column) if ok else np.int32(-1)
            moved[u] = np.int16(fixed) if valid else HOLE  # a hole marks the view it was in
        for u in range(width):
            q = places[u]
            if q >= 0:  # a store either way, so that holes among valid pixels cost no mispredicted branch
                here = target[q]
                wins = (moved[u] > here) | (here == UNSEEN)
                target[q] = moved[u] if wins else here
                if weighted:
                    target_weights[q] = source_weights[start + u] if wins else target_weights[q]
    _close_cracks(target, target_weights, weighted, width, limit)


def _mean_disparity(values: np.ndarray) -> np.float32:
    """The mean of a frame's valid values (1/16 px) over every 16th pixel; 0 when none."""
    total, count = np.float32(0.0), np.float32(0.0)
    for p in range(0, values.size, 16):
        valid = values[p] > UNSEEN
        total += np.float32(values[p]) if valid else np.float32(0.0)
        count += np.float32(1.0) if valid else np.float32(0.0)
    return total / count if count > np.float32(0.0) else np.float32(0.0)


def _close_cracks(values: np.ndarray, weights: np.ndarray, weighted: bool, width: int, limit: np.int32) -> None:
    """A hole between two valid neighbours within `limit` (left and right, else above and below) takes
    their mean, and the lower of their confidences. Row by row, from a copy of the row, on row views
    indexed from 0 (branch-free and without negative indices, so it vectorises); a hole filled in one
    row counts as valid for the row below."""
    height = values.size // width
    row = np.empty(width, np.int32)
    filled = np.empty(width, np.uint8)  # per pixel: 0 kept, 1 from left and right, 2 from above and below
    row_weights = np.empty(width, np.uint8)
    for v in range(1, height - 1):
        above = values[(v - 1) * width : v * width]
        here = values[v * width : (v + 1) * width]
        below = values[(v + 1) * width : (v + 2) * width]
        for u in range(width):
            row[u] = here[u]
        for u in range(width - 2):
            left, centre, right = row[u], row[u + 1], row[u + 2]
            up, down = np.int32(above[u + 1]), np.int32(below[u + 1])
            across = (left > UNSEEN) & (right > UNSEEN) & (np.abs(left - right) <= limit)
            along = (up > UNSEEN) & (down > UNSEEN) & (np.abs(up - down) <= limit)
            fill = (centre <= UNSEEN) & (across | along)
            mean = (left + right) >> 1 if across else (up + down) >> 1
            here[u + 1] = np.int16(mean) if fill else np.int16(centre)
            filled[u + 1] = (np.uint8(1) if across else np.uint8(2)) if fill else np.uint8(0)
        if weighted:
            _crack_weights(weights, filled, v, width, row_weights)


def _crack_weights(weights: np.ndarray, filled: np.ndarray, v: int, width: int, row: np.ndarray) -> None:
    """The confidences of row `v`'s closed cracks (`filled`: 1 from left and right, 2 from above and below),
    from a copy of the row (`row`, scratch), branch-free and on views indexed from 0, so it vectorises."""
    above = weights[(v - 1) * width : v * width]
    here = weights[v * width : (v + 1) * width]
    below = weights[(v + 1) * width : (v + 2) * width]
    for u in range(width):
        row[u] = here[u]
    for u in range(width - 2):
        across = min(row[u], row[u + 2])
        along = min(above[u + 1], below[u + 1])
        kind = filled[u + 1]
        here[u + 1] = across if kind == 1 else (along if kind == 2 else row[u + 1])


def _decays(alpha: float, history: int) -> np.ndarray:
    """Each age's weight in the average, newest first: alpha, then falling by 1 - alpha a frame; 0 from
    `history` on."""
    decays = np.zeros(MAX_HISTORY, np.float32)
    decay, keep = np.float32(alpha), np.float32(1.0) - np.float32(alpha)
    for age in range(history):
        decays[age] = decay
        decay *= keep
    return decays


def _filter_pixels(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    decays: np.ndarray,
    short: np.ndarray,
    delta: np.float32,
    persistence: np.float32,
    presence: np.float32,
    older_valid: np.ndarray,
    older_frames: np.float32,
    out: np.ndarray,
    parts: int,
) -> None:
    """Per pixel, in two passes: over the short window (`history`) each of the values of the three newest
    frames is a candidate, tested by persistence and the disagree rule, and the best that passes is
    chosen; over the long run that one is vetted by presence and, when its supporters alternate with
    conflicting frames, the long-run majority. Output: its weighted average (candidate + the average
    offset of its supporters, so equal values average to themselves exactly), rounded to 1/16 px; none
    chosen, or vetoed: invalid.

    `slots`: the LONG_RUN rows, newest first (rows of frames before a restart are UNSEEN: they vote for
    nothing); `short[age]` 1 for the frames of the short window, else 0 (and `decays[age]` 0).
    `presence`: the share of the frames that saw a pixel it must be valid in: the ring's, and the
    `older_frames` of this view before them (the pixel valid in `older_valid` of those). The pixels are
    cut into `parts` runs, one per thread; each pixel's result is the same whatever the count."""
    for part in prange(parts):
        _filter_range(
            values,
            weights,
            slots,
            decays,
            short,
            delta,
            persistence,
            presence,
            older_valid,
            older_frames,
            out,
            part * out.size // parts,
            (part + 1) * out.size // parts,
        )


def _filter_range(
    values: np.ndarray,
    weights: np.ndarray | None,
    slots: np.ndarray,
    decays: np.ndarray,
    short: np.ndarray,
    delta: np.float32,
    persistence: np.float32,
    presence: np.float32,
    older_valid: np.ndarray,
    older_frames: np.float32,
    out: np.ndarray,
    first: int,
    last: int,
) -> None:
    """`_filter_pixels` on the pixels first..last-1. The frames are added one by one (`_add_frame` and
    `_long_vote`, inlined), newest first, on row views indexed from 0, so that each pixel's sums stay in
    registers and the pixel loop vectorises; numba compiles the `weights is None` case (no confidence)
    without them."""
    one = np.float32(1.0)
    limit = delta * np.float32(SUBPIXELS)
    long_limit = limit * np.float32(2.0)
    r = _frame_rows(values, slots, first, last)
    d = _ages(decays)
    h = _ages(short)
    result = out[first:last]
    older = older_valid[first:last]
    if weights is None:
        for i in range(last - first):
            a, b, c = np.float32(r[0][i]), np.float32(r[1][i]), np.float32(r[2][i])
            s = _NO_SUMS
            s = _add_frame(s, r[0][i], one, d[0], h[0], a, b, c, limit)
            s = _add_frame(s, r[1][i], one, d[1], h[1], a, b, c, limit)
            s = _add_frame(s, r[2][i], one, d[2], h[2], a, b, c, limit)
            s = _add_frame(s, r[3][i], one, d[3], h[3], a, b, c, limit)
            s = _add_frame(s, r[4][i], one, d[4], h[4], a, b, c, limit)
            s = _add_frame(s, r[5][i], one, d[5], h[5], a, b, c, limit)
            s = _add_frame(s, r[6][i], one, d[6], h[6], a, b, c, limit)
            s = _add_frame(s, r[7][i], one, d[7], h[7], a, b, c, limit)
            x, mean = _chosen(s, a, b, c, persistence)
            t = _NO_LONG_RUN
            t = _long_vote(t, r[0][i], one, x, long_limit)
            t = _long_vote(t, r[1][i], one, x, long_limit)
            t = _long_vote(t, r[2][i], one, x, long_limit)
            t = _long_vote(t, r[3][i], one, x, long_limit)
            t = _long_vote(t, r[4][i], one, x, long_limit)
            t = _long_vote(t, r[5][i], one, x, long_limit)
            t = _long_vote(t, r[6][i], one, x, long_limit)
            t = _long_vote(t, r[7][i], one, x, long_limit)
            t = _long_vote(t, r[8][i], one, x, long_limit)
            t = _long_vote(t, r[9][i], one, x, long_limit)
            t = _long_vote(t, r[10][i], one, x, long_limit)
            t = _long_vote(t, r[11][i], one, x, long_limit)
            t = _long_vote(t, r[12][i], one, x, long_limit)
            t = _long_vote(t, r[13][i], one, x, long_limit)
            t = _long_vote(t, r[14][i], one, x, long_limit)
            t = _long_vote(t, r[15][i], one, x, long_limit)
            result[i] = mean if _long_run_passes(t, presence, older[i], older_frames) else np.float32(np.nan)
    else:
        w = _frame_rows(weights, slots, first, last)
        for i in range(last - first):
            a, b, c = np.float32(r[0][i]), np.float32(r[1][i]), np.float32(r[2][i])
            s = _NO_SUMS
            s = _add_frame(s, r[0][i], np.float32(w[0][i]), d[0], h[0], a, b, c, limit)
            s = _add_frame(s, r[1][i], np.float32(w[1][i]), d[1], h[1], a, b, c, limit)
            s = _add_frame(s, r[2][i], np.float32(w[2][i]), d[2], h[2], a, b, c, limit)
            s = _add_frame(s, r[3][i], np.float32(w[3][i]), d[3], h[3], a, b, c, limit)
            s = _add_frame(s, r[4][i], np.float32(w[4][i]), d[4], h[4], a, b, c, limit)
            s = _add_frame(s, r[5][i], np.float32(w[5][i]), d[5], h[5], a, b, c, limit)
            s = _add_frame(s, r[6][i], np.float32(w[6][i]), d[6], h[6], a, b, c, limit)
            s = _add_frame(s, r[7][i], np.float32(w[7][i]), d[7], h[7], a, b, c, limit)
            x, mean = _chosen(s, a, b, c, persistence)
            t = _NO_LONG_RUN
            t = _long_vote(t, r[0][i], np.float32(w[0][i]), x, long_limit)
            t = _long_vote(t, r[1][i], np.float32(w[1][i]), x, long_limit)
            t = _long_vote(t, r[2][i], np.float32(w[2][i]), x, long_limit)
            t = _long_vote(t, r[3][i], np.float32(w[3][i]), x, long_limit)
            t = _long_vote(t, r[4][i], np.float32(w[4][i]), x, long_limit)
            t = _long_vote(t, r[5][i], np.float32(w[5][i]), x, long_limit)
            t = _long_vote(t, r[6][i], np.float32(w[6][i]), x, long_limit)
            t = _long_vote(t, r[7][i], np.float32(w[7][i]), x, long_limit)
            t = _long_vote(t, r[8][i], np.float32(w[8][i]), x, long_limit)
            t = _long_vote(t, r[9][i], np.float32(w[9][i]), x, long_limit)
            t = _long_vote(t, r[10][i], np.float32(w[10][i]), x, long_limit)
            t = _long_vote(t, r[11][i], np.float32(w[11][i]), x, long_limit)
            t = _long_vote(t, r[12][i], np.float32(w[12][i]), x, long_limit)
            t = _long_vote(t, r[13][i], np.float32(w[13][i]), x, long_limit)
            t = _long_vote(t, r[14][i], np.float32(w[14][i]), x, long_limit)
            t = _long_vote(t, r[15][i], np.float32(w[15][i]), x, long_limit)
            result[i] = mean if _long_run_passes(t, presence, older[i], older_frames) else np.float32(np.nan)


def _frame_rows(frames: np.ndarray, slots: np.ndarray, first: int, last: int) -> tuple[np.ndarray, ...]:
    """The LONG_RUN stored frames' pixels first..last-1, newest first, as views indexed from 0."""
    return (
        frames[slots[0], first:last],
        frames[slots[1], first:last],
        frames[slots[2], first:last],
        frames[slots[3], first:last],
        frames[slots[4], first:last],
        frames[slots[5], first:last],
        frames[slots[6], first:last],
        frames[slots[7], first:last],
        frames[slots[8], first:last],
        frames[slots[9], first:last],
        frames[slots[10], first:last],
        frames[slots[11], first:last],
        frames[slots[12], first:last],
        frames[slots[13], first:last],
        frames[slots[14], first:last],
        frames[slots[15], first:last],
    )


def _ages(per_age: np.ndarray) -> tuple[np.float32, ...]:
    """The first MAX_HISTORY values per age (those of the short window) as scalars, kept in registers."""
    return (
        per_age[0],
        per_age[1],
        per_age[2],
        per_age[3],
        per_age[4],
        per_age[5],
        per_age[6],
        per_age[7],
    )


# Short window, per candidate (a, b, c): support (frames), trust (their confidence), against (the
# conflicting frames' confidence), weight and offset (the average's).
_NO_VOTES: tuple[np.float32, ...] = (np.float32(0.0),) * 5
_NO_SUMS: tuple[tuple[np.float32, ...], ...] = (_NO_VOTES, _NO_VOTES, _NO_VOTES)
# Long run, for the chosen candidate: for and against (confidence), the conflicting frames seen so far
# (newest first), the supporting frames older than one of them (> 0: interleaved), the valid frames, the
# frames that saw the pixel (not UNSEEN).
_NO_LONG_RUN: tuple[np.float32, ...] = (np.float32(0.0),) * 6


def _passes(votes: tuple[np.float32, ...], x: np.float32, persistence: np.float32) -> bool:
    """A candidate's short-window rules: persistence and the disagree rule."""
    support, trust, against, _, _ = votes
    return bool((x > np.float32(UNSEEN)) & (support >= persistence) & (trust >= against))


def _chosen(
    sums: tuple[tuple[np.float32, ...], ...],
    a: np.float32,
    b: np.float32,
    c: np.float32,
    persistence: np.float32,
) -> tuple[np.float32, np.float32]:
    """Each candidate's test, then a choice, newest first, without a branch to mispredict: the chosen
    candidate (HOLE: none) and its average rounded to 1/16 px (NaN: none)."""
    zero = np.float32(0.0)
    votes_a, votes_b, votes_c = sums
    mean_a = a + (votes_a[4] / votes_a[3] if votes_a[3] > zero else zero)
    mean_b = b + (votes_b[4] / votes_b[3] if votes_b[3] > zero else zero)
    mean_c = c + (votes_c[4] / votes_c[3] if votes_c[3] > zero else zero)
    pass_a = _passes(votes_a, a, persistence)
    best = votes_a[1] if pass_a else np.float32(-1.0)
    x = a if pass_a else np.float32(HOLE)
    mean = mean_a if pass_a else np.float32(np.nan)
    pass_b = _passes(votes_b, b, persistence) & (votes_b[1] > best)
    best = votes_b[1] if pass_b else best
    x = b if pass_b else x
    mean = mean_b if pass_b else mean
    pass_c = _passes(votes_c, c, persistence) & (votes_c[1] > best)
    x = c if pass_c else x
    mean = mean_c if pass_c else mean
    return x, np.float32(np.rint(mean) * np.float32(1.0 / SUBPIXELS))  # NaN stays NaN


def _long_run_passes(
    long_run: tuple[np.float32, ...], presence: np.float32, older_valid: np.uint8, older_frames: np.float32
) -> bool:
    """The long-run rules: presence, over the ring's frames that saw the pixel and the `older_frames`
    before them in this view (valid in `older_valid` of those), and a majority when supporters and
    conflicts interleave (a pixel that keeps switching between two surfaces, half and half, is output as
    neither)."""
    long_for, long_against, _, interleaved, valid, seen = long_run
    present = valid + np.float32(older_valid) >= presence * (seen + older_frames)
    return bool(present & ((interleaved == np.float32(0.0)) | (long_for > long_against)))


def _long_vote(
    long_run: tuple[np.float32, ...], value: np.int16, confidence: np.float32, x: np.float32, limit: np.float32
) -> tuple[np.float32, ...]:
    """The chosen candidate `x`'s long-run sums after one frame's value (1/16 px; `limit` too: twice
    the short window's, so that noise spread wider than `delta` still counts as one surface)."""
    long_for, long_against, conflicts, interleaved, frames, seen = long_run
    v = np.float32(value)
    valid = np.float32(1.0) if value > UNSEEN else np.float32(0.0)
    agree = np.float32(1.0) if abs(v - x) <= limit else np.float32(0.0)
    conflict = valid - valid * agree
    return (
        long_for + agree * confidence,
        long_against + conflict * confidence,
        conflicts + conflict,
        interleaved + agree * conflicts,  # frames come newest first: a conflict counted is a newer one
        frames + valid,
        seen + (np.float32(1.0) if value != UNSEEN else np.float32(0.0)),
    )


def _vote(
    votes: tuple[np.float32, ...],
    v: np.float32,
    valid: np.float32,
    candidate: np.float32,
    confidence: np.float32,
    decay: np.float32,
    short: np.float32,
    limit: np.float32,
) -> tuple[np.float32, ...]:
    """One candidate's short-window sums after one frame's value `v` (1/16 px; `limit` too): a frame
    within `limit` supports it, another valid frame conflicts; `short` 0: the frame is outside `history`."""
    support, trust, against, weight, offset = votes
    d = v - candidate
    agree = (np.float32(1.0) if abs(d) <= limit else np.float32(0.0)) * short
    conflict = valid * short - agree
    weighted = decay * confidence
    return (
        support + agree,
        trust + agree * confidence,
        against + conflict * confidence,
        weight + agree * weighted,
        offset + agree * weighted * d,
    )


def _add_frame(
    sums: tuple[tuple[np.float32, ...], ...],
    value: np.int16,
    confidence: np.float32,
    decay: np.float32,
    short: np.float32,
    a: np.float32,
    b: np.float32,
    c: np.float32,
    limit: np.float32,
) -> tuple[tuple[np.float32, ...], ...]:
    """One frame's value into a pixel's short-window sums: `_vote` for candidates a, b and c. A HOLE
    agrees with a HOLE only, and a HOLE candidate never passes."""
    v = np.float32(value)
    valid = np.float32(1.0) if value > UNSEEN else np.float32(0.0)
    votes_a, votes_b, votes_c = sums
    return (
        _vote(votes_a, v, valid, a, confidence, decay, short, limit),
        _vote(votes_b, v, valid, b, confidence, decay, short, limit),
        _vote(votes_c, v, valid, c, confidence, decay, short, limit),
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
    module["_vote"] = numba.njit(cache=True, inline="always")(_vote)
    module["_long_vote"] = numba.njit(cache=True, inline="always")(_long_vote)
    module["_long_run_passes"] = numba.njit(cache=True, inline="always")(_long_run_passes)
    module["_passes"] = numba.njit(cache=True, inline="always")(_passes)
    module["_add_frame"] = numba.njit(cache=True, inline="always")(_add_frame)
    module["_chosen"] = numba.njit(cache=True, inline="always")(_chosen)
    module["_frame_rows"] = numba.njit(cache=True, inline="always")(_frame_rows)
    module["_ages"] = numba.njit(cache=True, inline="always")(_ages)
    module["_filter_range"] = numba.njit(cache=True, nogil=True)(_filter_range)
    module["_crack_weights"] = numba.njit(cache=True, nogil=True, error_model="numpy")(_crack_weights)
    module["_mean_disparity"] = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(
        _mean_disparity
    )
    module["_close_cracks"] = numba.njit(cache=True, nogil=True, error_model="numpy")(_close_cracks)
    module["_warp_row"] = numba.njit(cache=True, nogil=True, error_model="numpy")(_warp_row)  # no zero checks:
    # a division by zero gives inf, which the projection's tests reject, and the loop vectorises
    return {
        "store": numba.njit(cache=True, nogil=True, parallel=True)(_store),
        "age_out": numba.njit(cache=True, nogil=True, parallel=True)(_age_out),
        "filter": numba.njit(cache=True, nogil=True, parallel=True)(_filter_pixels),
        "warp": numba.njit(cache=True, nogil=True, parallel=True)(_warp_rows),
    }
