"""Census-transform + semi-global matching core, and an edge-aware hole filler.

The recipe is the standard CPU one (Zabih & Woodfill census, Hirschmueller SGM):

    census (7x9 window, 62 bits in one uint64)
      -> Hamming cost volume C[y, x, d] (uint8, box-summed over ``window_size``; costs and P1/P2
         shifted right together until the path costs fit 8 bits, see ``cost_shift``)
      -> 6-path scanline aggregation S = sum_r L_r (L_r uint8, S uint16), P2 shrunk across edges
         (a coarse path from below first, then the five from above and the side in two row strips
         side by side that stay in cache, see ``_strips_select``)
      -> winner-take-all + uniqueness on S, row by row as soon as S of the row is complete
      -> right disparity from the same S (argmin along the diagonal), left-right check
      -> parabola sub-pixel fit -> hole-aware 3x3 median -> speckle removal
      -> gap closing: short consistent row gaps interpolated, occlusion-shaped gaps and the
         left-border strip given the background value beside them.

One job per module: ``registry`` (numba kernels, compiled together on first use), ``census``,
``aggregation`` (Hamming costs, path sums and the selection they feed), ``postprocess`` (gap
closing, median, speckles) and ``fill`` (``fill_holes``); ``census_sgm`` below runs them in order.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterable

import numpy as np

from stereo_depth.core.census_sgm import aggregation, postprocess
from stereo_depth.core.census_sgm import census as transform
from stereo_depth.core.census_sgm.aggregation import cost_shift
from stereo_depth.core.census_sgm.fill import fill_holes
from stereo_depth.core.census_sgm.registry import compile_all

__all__ = ["census_sgm", "compile_kernels", "cost_shift", "fill_holes"]


def census_sgm(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int,
    num_disparities: int,
    window_size: int,
    P1: float,
    P2: float,
    uniqueness_ratio: float,
    disp12_max_diff: int,
    census_size: tuple[int, int] = transform.CENSUS_SIZE,
    p2_gamma: float = 4.0,
    paths: int = 6,
    median: bool = True,
    speckle_size: int = 100,
    speckle_range: float = 1.0,
    conf_gain: float = 1.5,
    lr_penalty: float = 0.5,
    gap_max: int = 20,
    gap_tol: float = 2.0,
    occlusion_margin: int = 2,
    border_margin: int = 1,
    gap_confidence: float = 0.2,
    timings: dict[str, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Census + SGM disparity of a rectified pair.

    left/right: rectified uint8 grey HxW, left is the reference. Returns (disparity, confidence):
    disparity float32 HxW in pixels with d = x_left - x_right, sub-pixel, NaN where invalid
    (failed LR check, not unique, outside search range); confidence float32 HxW in [0, 1]
    (0 where invalid).

    ``window_size`` box-sums the Hamming costs (1 = census only; odd). P1/P2 are in units of
    census bits x window area. ``uniqueness_ratio`` is a percentage as in OpenCV; ``disp12_max_diff``
    < 0 disables the left-right check. ``census_size`` is (height, width), at most 63 bits.
    ``paths`` is 5 (horizontal + the three from the row above), aggregated in one top-down pass per
    row strip with nothing of volume size in memory (``_strips_select``); 6 (those and the path from
    below, computed first on every other row and column: ``_bottom_up``; within 0.0011 of 8 in bad-1,
    bad-2, bad-2 of estimated pixels and density over the 38 scenes, where 5 paths are 0.010 worse in
    bad-1); 4 (horizontal + vertical) or 8, aggregated by two sweeps over the whole cost volume.
    ``speckle_size`` 0 disables speckle removal.
    Confidence is the cost margin (second - best) / second times ``conf_gain``, clipped to 1 and
    scaled by ``lr_penalty`` where the two views disagree by a pixel.

    Gap closing (after the speckle filter, row by row; see ``_close_gaps``) fills only holes whose
    value the surrounding measurements pin down; the rest stay NaN for ``fill_holes``:

    * a run of at most ``gap_max`` holes whose two bounding values differ by at most ``gap_tol``
      is linearly interpolated (pixels the uniqueness / LR checks dropped inside a surface);
    * a run whose right neighbour is nearer by more than ``gap_tol`` and whose length is at most
      that disparity step + ``occlusion_margin`` is the strip a foreground edge hides from the
      right camera: it takes the left (background) value;
    * a run starting at column 0 no longer than the disparity bounding it + ``border_margin`` is
      the strip with no counterpart in the right image: it takes that value.

    Filled pixels get confidence ``gap_confidence``. ``gap_max`` 0 disables interpolation,
    a negative ``occlusion_margin`` / ``border_margin`` disables those fills.

    ``timings``, when given, receives each step's milliseconds (``STEPS``; docs/design/decisions.md).
    """
    _check_inputs(left, right, min_disparity, num_disparities, window_size, census_size, paths)
    compile_all()
    start = time.perf_counter()
    left = np.ascontiguousarray(left)  # a crop or a view would make numba compile another variant
    cl, cr = transform.census_pair(left, right, census_size)
    census: tuple[np.ndarray, np.ndarray] | None = (cl, cr)  # window 1: costs computed where the paths need them
    start = _lap(timings, "census", start)
    shift, p1, p2 = cost_shift(census_size[0] * census_size[1] - 1, window_size, P1, P2)
    vol, acc = aggregation._workspace(left.shape, int(num_disparities))  # strips, window 1: left untouched
    if window_size > 1:
        aggregation._hamming_volume(cl, cr, int(min_disparity), vol)
        vol = aggregation._box_sum(vol, window_size, shift)
        census = None
    select = (int(min_disparity), uniqueness_ratio / 100.0, int(disp12_max_diff), float(conf_gain), float(lr_penalty))
    sgm = (p1, p2, float(p2_gamma), paths)
    if paths in (5, 6):  # row strips; 6 adds the path from below, computed first
        up = aggregation.NO_PATH_FROM_BELOW
        if paths == 6:
            up = aggregation._bottom_up(vol, census, shift, left, sgm, int(min_disparity))
        if window_size > 1:
            disp, conf = aggregation._strips_select_volume(vol, left, sgm, select, up)
        else:
            disp, conf = aggregation._strips_select(vol, (cl, cr), shift, left, sgm, select, up)
    else:
        disp, conf = aggregation._aggregate_select(vol, census, shift, left, acc, sgm, select)
    start = _lap(timings, "costs, paths and selection", start)
    if median:
        disp = postprocess._median3(disp, aggregation.HOLE)
    start = _lap(timings, "median", start)
    if speckle_size > 0:
        postprocess._remove_speckles(disp, speckle_size, speckle_range)
    start = _lap(timings, "speckles", start)
    gaps = (int(gap_max), np.float32(gap_tol), int(occlusion_margin), int(border_margin), np.float32(gap_confidence))
    disp = postprocess._finish(disp, conf, aggregation.HOLE, gaps)
    _lap(timings, "gap closing", start)
    return disp, conf


STEPS = ("census", "costs, paths and selection", "median", "speckles", "gap closing")  # census_sgm's ``timings``


def _lap(timings: dict[str, float] | None, step: str, start: float) -> float:
    """Record the ms since ``start`` as ``step`` in ``timings`` (if given); returns now."""
    now = time.perf_counter()
    if timings is not None:
        timings[step] = (now - start) * 1000.0
    return now


#: (window_size, paths) with kernels of their own: window 1 and 3, the strips (6 paths) and the sweeps (8)
KERNEL_VARIANTS = tuple(itertools.product((1, 3), (6, 8)))


def compile_kernels(variants: Iterable[tuple[int, int]] = KERNEL_VARIANTS, *, fill: bool = True) -> str:
    """Compile every kernel (or load it from numba's cache) now; returns the cache folder.

    The first compile takes one to two minutes per install, then each process loads machine code in
    well under a second: ``stereo-depth compile`` runs this at install time so a robot's first frame
    does not wait (and splits it over two processes: ``variants`` and ``fill`` name a share). The cache
    sits in NUMBA_CACHE_DIR when that is set, else in ``__pycache__`` beside the kernel modules when
    writable (else numba's per-user folder).
    """
    image = np.zeros((24, 48), np.uint8)
    for window_size, paths in variants:
        census_sgm(
            image,
            image,
            min_disparity=0,
            num_disparities=16,
            window_size=window_size,
            P1=20,
            P2=200,
            uniqueness_ratio=3,
            disp12_max_diff=1,
            paths=paths,
        )
    if fill:
        holes = np.full(image.shape, 20.0, np.float32)
        holes[::2, ::3] = np.nan  # some holes, not all: a disparity with none or only holes fills nothing
        fill_holes(holes, image)
        fill_holes(holes, image, scanline=False)
    compile_all()
    return str(vars(transform)["_census"]._cache._cache_path)  # the dispatcher compile_all put there


def _check_inputs(
    left: np.ndarray, right: np.ndarray, min_d: int, nd: int, window: int, census: tuple[int, int], paths: int
) -> None:
    """Refuse inputs the kernels would silently mis-handle."""
    if left.dtype != np.uint8 or right.dtype != np.uint8 or left.ndim != 2 or left.shape != right.shape:
        msg = (
            "census_sgm needs two uint8 grey images of one size, "
            f"got {left.dtype}{left.shape} and {right.dtype}{right.shape}"
        )
        raise ValueError(msg)
    if min_d < 0:  # the kernels would index right-image columns past the right border
        msg = f"min_disparity must be >= 0, got {min_d}"
        raise ValueError(msg)
    if nd < 1:
        msg = f"num_disparities must be >= 1, got {nd}"
        raise ValueError(msg)
    if window < 1 or window % 2 == 0:
        msg = f"window_size must be odd and >= 1, got {window}"
        raise ValueError(msg)
    if census[0] % 2 == 0 or census[1] % 2 == 0 or census[0] * census[1] - 1 > 64:
        msg = f"census_size must be odd x odd with at most 64 neighbours, got {census}"
        raise ValueError(msg)
    if paths not in (4, 5, 6, 8):
        msg = f"paths must be 4, 5, 6 or 8, got {paths}"
        raise ValueError(msg)
