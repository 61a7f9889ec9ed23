"""The temporal filter (core/temporal.py): what reaches depth and points2 frame after frame."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from stereo_depth.core.temporal import (
    LONG_RUN,
    PRESENCE_RUN,
    TemporalFilter,
    TemporalSettings,
    lead_in_frames,
)
from stereo_depth.errors import ParameterError

PERIOD_NS = 33_333_333
SETTINGS = TemporalSettings()  # the defaults: alpha 0.2, delta 2 px, 4 of the last 8 frames, valid in 0.4
CALIBRATION = ("camera", 1)


def frame(value: float, shape: tuple[int, int] = (4, 6)) -> np.ndarray:
    return np.full(shape, value, np.float32)


def feed(temporal: TemporalFilter, frames: list[np.ndarray], first: int = 0, **kw: object) -> list[np.ndarray]:
    """Each frame through the filter, 30 Hz stamps from frame number `first`."""
    settings = TemporalSettings(**kw) if kw else SETTINGS  # type: ignore[arg-type]
    return [temporal.apply(d, None, (first + k) * PERIOD_NS, CALIBRATION, settings) for k, d in enumerate(frames)]


def test_a_pixel_seen_once_never_reaches_the_output() -> None:
    wall = [frame(20.0) for _ in range(12)]
    for k, d in enumerate(wall):
        d[1, 2] = 50.0 if k == 5 else np.nan  # a wrong match in one frame, nothing before or after
        d[2, 3] = 50.0 if k == 7 else d[2, 3]  # a wrong value once on a seen surface
    out = feed(TemporalFilter(), wall)
    assert all(np.isnan(o[1, 2]) for o in out)
    assert all(o[2, 3] != 50.0 for o in out)
    assert out[7][2, 3] == pytest.approx(20.0)  # the surface's value stands in for the one-off
    seen = SETTINGS.persistence
    assert np.isnan(out[seen - 2]).all() and np.isnan(out[seen - 1]).sum() == 1  # valid once seen in 4 frames


def test_noise_is_averaged_and_a_changed_value_restarts_the_average() -> None:
    rng = np.random.default_rng(0)
    noisy = [frame(10.0, (40, 40)) + rng.normal(0, 0.3, (40, 40)).astype(np.float32) for _ in range(10)]
    moved = [frame(30.0, (40, 40)) for _ in range(5)]  # an object arrives: 20 px more
    out = feed(TemporalFilter(), noisy + moved)
    assert np.std(out[9] - 10.0) < 0.6 * np.std(noisy[9] - 10.0)
    for k in (10, 11):  # one or two frames of the new value: not yet trusted, the old one stands (a trail)
        assert np.abs(out[k] - 10.0).max() < 1.0
    assert np.isnan(out[12]).all()  # three frames of it: not the old value any more, not yet the new
    np.testing.assert_array_equal(out[13], 30.0)  # as many frames of it as of the old: alone, no blend


def test_a_pixel_whose_noise_spreads_wider_than_delta_stays_valid() -> None:
    """A textureless patch: the newest value is often at the edge of the spread (17 after 23), but a
    value of the last three frames (20) agrees with most of the history: the pixel never blinks."""
    cycle = [20.0, 20.0, 23.0, 17.0]
    out = feed(TemporalFilter(), [frame(cycle[k % 4]) for k in range(16)])
    for o in out[8:]:
        assert not np.isnan(o).any()
        assert np.abs(o - 20.0).max() <= SETTINGS.delta


def test_a_wrong_match_that_comes_back_in_runs_where_the_pixel_is_mostly_a_hole_is_never_output() -> None:
    """A real sensor's errors repeat: runs of 5 frames pass persistence, not presence (0.4 of the frames;
    these come back in 5 of every 16)."""
    frames = [frame(np.nan) for _ in range(80)]
    for k, d in enumerate(frames):
        if k % 8 < 4:  # valid in half the frames: in runs of 4 with 4-frame holes between
            d[0, 0] = 20.0
        if k % 16 < 5:  # valid in 5 of every 16 frames, in runs of 5
            d[1, 1] = 50.0
    out = feed(TemporalFilter(), frames)
    assert all(np.isnan(o[1, 1]) for o in out[3 * LONG_RUN :])  # (before, few frames tell the share)
    assert all(o[0, 0] == 20.0 for o in out[LONG_RUN:] if not np.isnan(o[0, 0]))
    assert sum(not np.isnan(o[0, 0]) for o in out[LONG_RUN:]) >= (len(out) - LONG_RUN) // 2


def test_on_a_still_view_presence_looks_back_further_than_the_last_16_frames() -> None:
    """A wrong match that comes back in runs of 8 frames every 24: half of a 16-frame window while it
    lasts, a third of the frames over the long run. While the view holds still, presence counts up to
    PRESENCE_RUN frames, so it never reaches the output; a pixel valid in half the frames does."""
    frames = [frame(np.nan) for _ in range(PRESENCE_RUN + 72)]
    for k, d in enumerate(frames):
        if k % 24 < 8:
            d[0, 0] = 30.0
        if k % 24 < 12:
            d[1, 1] = 40.0
    out = feed(TemporalFilter(), frames)
    assert all(np.isnan(o[0, 0]) for o in out[4 * 24 :])
    assert sum(o[1, 1] == 40.0 for o in out[PRESENCE_RUN:]) >= 0.4 * (len(out) - PRESENCE_RUN)


def test_a_restart_forgets_the_frames_presence_counted() -> None:
    """A pixel that was a hole for a long time, then valid after the stream restarted (a stamp gap: the
    camera may have been moved): it is output as soon as persistence allows, not held back by the holes
    of before."""
    frames = [frame(np.nan) for _ in range(PRESENCE_RUN)] + [frame(25.0) for _ in range(12)]
    temporal = TemporalFilter()
    feed(temporal, frames[:PRESENCE_RUN])
    out = feed(temporal, frames[PRESENCE_RUN:], first=PRESENCE_RUN + 10)
    assert all(np.isnan(o).all() for o in out[: SETTINGS.persistence - 1])
    assert all((o == 25.0).all() for o in out[SETTINGS.persistence - 1 :])


def test_a_value_that_alternates_with_the_pixels_long_run_value_is_not_output() -> None:
    """A wrong value that keeps coming back on a surface: each run of 4 passes the last 8 frames, not the
    long run, where the surface's value has more support."""
    frames = [frame(20.0) for _ in range(40)]
    for k, d in enumerate(frames):
        if k % 12 >= 8:  # 8 frames of the surface, then 4 of a wrong value, and again
            d[0, 0] = 50.0
    out = feed(TemporalFilter(), frames)
    assert all(o[0, 0] != 50.0 for o in out[12:])  # its first run is a clean change: no history against it
    assert sum(o[0, 0] == 20.0 for o in out[12:]) >= len(out[12:]) * 3 // 4


def test_a_candidate_with_more_frames_against_it_than_for_it_is_not_output() -> None:
    """The disagree rule, with persistence 3 so that it decides: 3 frames of 30 after 5 of 10."""
    values = [10.0] * 5 + [30.0] * 3
    out = feed(TemporalFilter(), [frame(v) for v in values], persistence=3)
    assert np.isnan(out[-1]).all()  # 30 has 3 frames for it and 5 against; 10 is not a candidate any more
    out = feed(TemporalFilter(), [frame(v) for v in [10.0] * 3 + [30.0] * 3], persistence=3)
    np.testing.assert_array_equal(out[-1], 30.0)  # as many for as against: passes


def test_support_and_conflict_are_weighed_by_confidence() -> None:
    """Four frames of 30 that the matcher hardly trusts against four of 10 that it trusts: not output;
    the same frames equally trusted pass (a tie)."""
    temporal = TemporalFilter()
    values, confidences = [10.0] * 4 + [30.0] * 4, [0.9] * 4 + [0.2] * 4
    for k, (value, confidence) in enumerate(zip(values, confidences, strict=True)):
        out = temporal.apply(frame(value), frame(confidence), k * PERIOD_NS, CALIBRATION, SETTINGS)
    assert np.isnan(out).all()
    even = TemporalFilter()
    for k, value in enumerate(values):
        out = even.apply(frame(value), frame(0.5), k * PERIOD_NS, CALIBRATION, SETTINGS)
    np.testing.assert_array_equal(out, 30.0)


@pytest.mark.parametrize("alpha", [0.2, 0.6, 1.0])
def test_the_value_is_the_average_with_the_newest_frame_weighted_by_alpha(alpha: float) -> None:
    """Seven frames of 10 then one of 11 (all within delta): alpha, then alpha (1 - alpha)^k for the frame
    k frames older; rounded to 1/16 px."""
    out = feed(TemporalFilter(), [frame(10.0)] * 7 + [frame(11.0)], alpha=alpha)[-1]
    weights = alpha * (1.0 - alpha) ** np.arange(8)
    expected = (11.0 * weights[0] + 10.0 * weights[1:].sum()) / weights.sum()
    np.testing.assert_array_equal(out, np.round(expected * 16.0) / 16.0)


def test_confidence_weights_each_frame() -> None:
    temporal = TemporalFilter()
    values, confidences = [10.0, 11.0, 10.0, 11.0], [0.9, 0.1, 0.9, 0.1]
    for k, (value, confidence) in enumerate(zip(values, confidences, strict=True)):
        out = temporal.apply(frame(value), frame(confidence), k * PERIOD_NS, CALIBRATION, SETTINGS)
    assert float(out[0, 0]) < 10.3  # plain alpha weighting would favour the newest (11)


@pytest.mark.parametrize(
    "break_at",
    [
        pytest.param(lambda k: (k - 20) * PERIOD_NS, id="stamp jumps back (looping bag)"),
        pytest.param(lambda k: (k + 10) * PERIOD_NS, id="gap of 10 frame periods"),
    ],
)
def test_history_is_forgotten_when_the_stream_breaks(break_at: object) -> None:
    temporal = TemporalFilter()
    feed(temporal, [frame(20.0) for _ in range(8)])
    stamp = break_at(8)  # type: ignore[operator]
    assert np.isnan(temporal.apply(frame(20.0), None, stamp, CALIBRATION, SETTINGS)).all()
    steady = TemporalFilter()
    feed(steady, [frame(20.0) for _ in range(8)])
    assert not np.isnan(steady.apply(frame(20.0), None, 8 * PERIOD_NS, CALIBRATION, SETTINGS)).any()


@pytest.mark.parametrize(("periods", "forgotten"), [(3, False), (5, True)])
def test_a_gap_of_more_than_four_frame_periods_restarts(periods: int, forgotten: bool) -> None:
    """Two dropped frames (a gap of 3 periods) keep the history; a gap of 5 periods forgets it."""
    temporal = TemporalFilter()
    feed(temporal, [frame(20.0) for _ in range(8)])
    out = temporal.apply(frame(20.0), None, (7 + periods) * PERIOD_NS, CALIBRATION, SETTINGS)
    assert np.isnan(out).all() == forgotten
    assert not np.isnan(out).any() or forgotten


def test_history_is_forgotten_when_the_calibration_changes() -> None:
    temporal = TemporalFilter()
    feed(temporal, [frame(20.0) for _ in range(8)])
    assert np.isnan(temporal.apply(frame(20.0), None, 8 * PERIOD_NS, ("camera", 2), SETTINGS)).all()


def test_motion_reset_restarts_every_pixel_when_all_change_at_once() -> None:
    before, after = [frame(20.0) for _ in range(8)], [frame(40.0)]
    kept = feed(TemporalFilter(), before + after)[-1]
    np.testing.assert_array_equal(kept, 20.0)  # off: one frame of the old view (then holes)
    reset = feed(TemporalFilter(), before + after, motion_reset=0.5)[-1]
    assert np.isnan(reset).all()
    part = frame(20.0)
    part[:1] = 40.0  # a quarter of the pixels changed: below the share, nothing restarts
    kept = feed(TemporalFilter(), [*before, part], motion_reset=0.5)[-1]
    np.testing.assert_array_equal(kept[1:], 20.0)


def test_while_the_view_moves_frames_pass_unfiltered_and_the_history_is_forgotten() -> None:
    """Without odometry the filter stands aside when the camera turns: the view shifts by 3 px a frame,
    so the history no longer lies under the same pixels; the raw disparity passes (no worse than no
    filter), and once the view holds still the filter takes over again as soon as persistence allows."""
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (480, 640)).astype(np.uint8), (5, 5), 0)  # a VGA view
    rows = np.arange(120, dtype=np.float32)[:, None]
    temporal = TemporalFilter()
    outs, raws = [], []
    for k in range(20):
        shift = 3 * k if k < 12 else 33  # turning, then still
        raw = (20.0 + rows / 10.0 + shift / 10.0 + rng.normal(0.0, 0.3, (120, 160))).astype(np.float32)
        view = np.roll(texture, shift, axis=0)
        outs.append(temporal.apply(raw, None, k * PERIOD_NS, CALIBRATION, SETTINGS, view=view))
        raws.append(raw)
    for k in range(1, 12):
        np.testing.assert_array_equal(outs[k], raws[k])  # moving: the matcher's disparity as it is
    for k in range(12, 10 + SETTINGS.persistence):  # (the last turn, frame 11, restarted the history)
        np.testing.assert_array_equal(outs[k], raws[k])  # still again: unfiltered until the history is refilled
    filtered = outs[-1]
    assert not np.array_equal(filtered, raws[-1]) and np.isfinite(filtered).mean() > 0.9
    assert np.std(filtered - filtered.mean()) < np.std(raws[-1] - raws[-1].mean())  # averaged again
    still = TemporalFilter()
    for k in range(8):
        out = still.apply(frame(20.0), None, k * PERIOD_NS, CALIBRATION, SETTINGS, view=texture)
    np.testing.assert_array_equal(out, 20.0)  # a still view: filtered as without the test


def test_an_object_crossing_a_still_view_does_not_make_the_filter_stand_aside() -> None:
    """One part of the view moves 8 px a frame (a person walking by), the rest holds still: the camera
    did not move, and the filter keeps filtering."""
    rng = np.random.default_rng(4)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (480, 640)).astype(np.uint8), (5, 5), 0)
    temporal = TemporalFilter()
    for k in range(10):
        view = texture.copy()
        view[160:288, 213:341] = np.roll(texture[160:288, 213:341], 8 * k, axis=1)
        raw = frame(20.0) + np.float32(0.1 * (k % 2))
        out = temporal.apply(raw, None, k * PERIOD_NS, CALIBRATION, SETTINGS, view=view)
    assert not np.array_equal(out, raw)  # filtered: the average, not this frame's values
    assert np.isfinite(out).all()


def test_the_output_depends_on_the_last_frames_only() -> None:
    """What lets a shard start with `lead_in_frames` frames and give what one pass gives: the last frames
    and the stamps that decide the restarts among them."""
    rng = np.random.default_rng(1)
    surface = rng.uniform(5, 60, (30, 30))
    holes = rng.uniform(0.3, 0.75, surface.shape)  # per pixel: many near the presence share

    def frames(n: int) -> list[np.ndarray]:
        """The surface with noise, holes in 30-75 % of the frames and wrong values in 10 %, fresh each frame."""
        out = []
        for _ in range(n):
            d = (surface + rng.normal(0.0, 0.7, surface.shape)).astype(np.float32)
            d[rng.random(d.shape) < 0.1] = rng.uniform(5, 60)
            d[rng.random(d.shape) < holes] = np.nan
            out.append(d)
        return out

    lead = lead_in_frames()
    past, common = frames(23), frames(lead + 5)
    # past frames 1 period apart, the common ones 2; a gap of 5 periods on the first frame whose restart
    # reaches the first output compared (through presence): a restart only when the stamps before it
    # include the past's
    gap_at = lead - PRESENCE_RUN + 2
    stamps = [k * PERIOD_NS for k in range(len(past))]
    for k in range(len(common)):
        stamps.append(stamps[-1] + (5 if k == gap_at else 2) * PERIOD_NS)
    settings = TemporalSettings()

    def run(first: int) -> list[np.ndarray]:
        temporal = TemporalFilter()
        sequence = (past + common)[first:]
        return [
            temporal.apply(d, None, t, CALIBRATION, settings) for d, t in zip(sequence, stamps[first:], strict=True)
        ]

    compared = list(zip(run(0)[-5:], run(len(past))[-5:], strict=True))
    assert all(np.isfinite(a).mean() > 0.3 for a, _ in compared)  # pixels pass: the rules decide them
    for a, b in compared:
        np.testing.assert_array_equal(a, b)


def test_settings_are_checked() -> None:
    with pytest.raises(ParameterError, match="temporal_persistence 9"):
        TemporalSettings(persistence=9).validate()
    with pytest.raises(ParameterError, match="temporal_alpha"):
        TemporalSettings(alpha=0.0).validate()


def test_start_up_compiles_every_kernel_a_stream_of_frames_runs() -> None:
    """`stereo-depth compile` and a node's start-up build them, so no frame, the 17th included (when
    presence starts counting older frames), waits for numba. In a process of its own: the other tests
    have run the kernels in this one."""
    check = (
        "from stereo_depth.core import temporal; temporal.compile_kernels(); "
        "print(sorted(name for name, kernel in temporal._kernels().items() if not kernel.signatures))"
    )
    result = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
