"""The temporal filter (core/temporal.py): what reaches depth and points2 frame after frame."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_depth.core.temporal import TemporalFilter, TemporalSettings, lead_in_frames
from stereo_depth.errors import ParameterError

PERIOD_NS = 33_333_333
SETTINGS = TemporalSettings()  # the defaults: alpha 0.4, delta 2 px, 4 of the last 8 frames
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


def test_the_output_depends_on_the_last_frames_only() -> None:
    """What lets a shard start with `lead_in_frames` frames and give what one pass gives."""
    rng = np.random.default_rng(1)

    def frames(n: int) -> list[np.ndarray]:
        out = []
        for _ in range(n):
            d = rng.uniform(5, 60, (30, 30)).astype(np.float32)
            d[rng.random(d.shape) < 0.3] = np.nan
            out.append(d)
        return out

    common = frames(lead_in_frames() + 5)
    long_past = feed(TemporalFilter(), frames(23) + common)[-5:]
    lead_in_only = feed(TemporalFilter(), common, first=23)[-5:]
    for a, b in zip(long_past, lead_in_only, strict=True):
        np.testing.assert_array_equal(a, b)


def test_settings_are_checked() -> None:
    with pytest.raises(ParameterError, match="temporal_persistence 9"):
        TemporalSettings(persistence=9).validate()
    with pytest.raises(ParameterError, match="temporal_alpha"):
        TemporalSettings(alpha=0.0).validate()
