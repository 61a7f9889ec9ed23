"""Processing parameters: one dataclass holds every default once, profiles are named sets of values.

Field names are the ROS parameter names (stereo_image_proc's where the meaning is the same), and each
field carries its description and allowed range in its metadata, so the ROS layer declares its
parameters from here and `config/stereo_depth.yaml` is checked against it. A profile only names the
values that differ from the dataclass defaults; explicitly given values always override a profile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from stereo_depth.core.option_fields import coerce, coerced, option, option_names, range_problems
from stereo_depth.core.spatial import SpatialSettings
from stereo_depth.core.temporal import TemporalSettings
from stereo_depth.errors import ParameterError

SGBM_MODES = {0: "SGBM", 1: "HH", 2: "SGBM_3WAY", 3: "HH4"}
SGBM_COST_MAX = 32767  # OpenCV SGBM's path costs are int16
CENSUS_BITS = 62  # census_sgm's 7x9 census: the largest Hamming cost of one pixel
CENSUS_P2_PER_BIT = 32  # census_sgm's P2 limit, in units of the largest matching cost (see census_sgm.cost_shift)
MATCHER_NAMES = ("bm", "sgbm", "census_sgm")  # core/matching.py's registry has one entry each


@dataclass(frozen=True)
class StereoParams:
    """Everything that changes what the pipeline computes for a frame; defaults = the `default` profile."""

    matcher: str = option(
        "sgbm",
        "Matching core by name: bm (OpenCV block matching), sgbm (OpenCV semi-global), "
        "census_sgm (our census + 6-path semi-global core)",
        choices=MATCHER_NAMES,
    )
    prefilter_size: int = option(9, "BM normalization window size in pixels (odd)", 5, 255, 2)
    prefilter_cap: int = option(31, "Bound on normalized pixel values", 1, 63, 1)
    correlation_window_size: int = option(5, "Matching window width in pixels (odd; BM needs >= 5)", 1, 255, 2)
    min_disparity: int = option(0, "Disparity to begin search at, pixels", -2048, 2048, 1)
    disparity_range: int = option(64, "Number of disparities to search, pixels (multiple of 16)", 16, 4096, 16)
    texture_threshold: int = option(10, "BM: reject windows whose texture response is below this", 0, 10000, 1)
    uniqueness_ratio: float = option(
        5.0, "Reject if the best match is not this % better than the next best", 0.0, 100.0
    )
    speckle_size: int = option(100, "Remove disparity blobs smaller than this many pixels (0 = off)", 0, 1000, 1)
    speckle_range: int = option(2, "Largest disparity step inside one blob, pixels", 0, 31, 1)
    disp12_max_diff: int = option(
        1,
        "Left-right check tolerance, pixels, every matcher: -1 = check off, N >= 1 = N px; 0 = what "
        "stereo_image_proc gives (bm: off, as it never passes it to BM; sgbm: 1 px, OpenCV's least; "
        "census_sgm: 0 px)",
        -1,
        128,
        1,
    )
    P1: float = option(
        200.0, "Smoothness penalty for disparity changes of 1 px (sgbm: grey levels, census_sgm: bits)", 0.0, 100000.0
    )
    P2: float = option(800.0, "SGBM penalty for larger disparity changes (must exceed P1)", 0.0, 100000.0)
    sgbm_mode: int = option(2, "SGBM variant: 0 SGBM (5 paths), 1 HH (8 paths), 2 SGBM_3WAY, 3 HH4", 0, 3, 1)
    census_paths: int = option(
        6,
        "census_sgm aggregation paths: 6 (those of 5 and a path from below on every other row and column, "
        "computed first; about as accurate as 8), 8 (two sweeps over the whole cost volume: the 4 straight "
        "paths and both diagonals both ways; the most accurate, the slowest) or 5 (the 2 horizontal paths "
        "and the 3 from the row above, one pass in row strips that stay in cache; the quickest, least "
        "accurate on slanted surfaces)",
        choices=(6, 8, 5),
    )
    confidence_threshold: float = option(
        0.0,
        "Invalidate pixels whose match confidence is below this (every matcher; one scale: a threshold keeps "
        "about the same share of pixels whichever matcher runs)",
        0.0,
        1.0,
    )
    # too near for the disparity range
    near_detection: bool = option(
        True,
        "Invalidate the pixels nearer than disparity_range can see (true disparity beyond it), which a "
        "matcher would put farther away: found by a coarse search over twice the range at 1/4 resolution "
        "and by the cost still falling at the range's top; they stay out of disparity, depth, points2 and "
        "points2_clearing, and fill_holes leaves them (near_points puts them in points2)",
    )
    fill_holes: bool = option(False, "Fill invalid pixels from their neighbours for a dense depth image")
    hole_fill_radius: int = option(
        3, "Edge-aware smoothing radius of filled pixels (0 = plain background fill)", 0, 7, 1
    )
    downsample: int = option(1, "Match at 1/downsample resolution (1, 2 or 4) for slow CPUs", 1, 4, 1)
    downsample_output: str = option(
        "full",
        "With downsample > 1: full (disparity, depth, points2, image_rect at the input size) or processed "
        "(at the matched size, focal length and principal point scaled with it: 1/downsample^2 the points)",
        choices=("full", "processed"),
    )

    temporal_filter: bool = option(
        False,
        "Filter the disparity over time before depth and points2: a pixel is output only when it agrees "
        "with temporal_persistence of the last temporal_history frames (no ghost points)",
    )
    temporal_alpha: float = option(
        0.2, "Temporal filter: the newest frame's weight in the per-pixel exponential average", 0.01, 1.0
    )
    temporal_delta: float = option(
        2.0,
        "Temporal filter: values within this many px agree (one surface); a value farther from the "
        "pixel's newest restarts its average",
        0.0,
        1e3,
    )
    temporal_persistence: int = option(
        4, "Temporal filter: frames of temporal_history a pixel must agree in to be output", 1, 8, 1
    )
    temporal_history: int = option(8, "Temporal filter: frames remembered per pixel", 1, 8, 1)
    temporal_motion_reset: float = option(
        0.0,
        "Temporal filter: restart every pixel when more than this share of them changed at once "
        "(the camera moved fast; 0 = off)",
        0.0,
        1.0,
    )
    temporal_presence: float = option(
        0.4,
        "Temporal filter: share of the frames a pixel must be valid in to be output: the last 16, and while "
        "the view holds still up to the last 128 (a wrong match in a place that is mostly a hole, even one "
        "that comes back for several frames in a row, is not)",
        0.0,
        1.0,
    )
    temporal_ego_motion: float = option(
        0.5,
        "Temporal filter: when the view shifts by more than this many px between frames (the camera turns or "
        "moves), forget the history and pass frames through unfiltered until it is refilled (0 = off)",
        0.0,
        100.0,
    )

    # Glare and the spatial filter (core/saturation.py, core/spatial.py)
    invalidate_saturated: bool = option(
        True,
        "No disparity, depth or points where either image is saturated without texture (a window, a lamp, "
        "glare on a floor): 9x9 blocks of pixels at full scale (saturation_level) in every channel; any "
        "match there is noise",
    )
    saturation_level: int = option(
        0,
        "Raw value at which a 16-bit camera's pixels saturate: 1023 for a 10-bit, 4095 for a 12-bit sensor "
        "(0 = 65535); 8-bit images saturate at 255. Judged on the camera's values, never the frame's peak",
        0,
        65535,
        1,
    )
    spatial_filter: bool = option(
        False,
        "Replace wrong matches by their surface's value (image-guided median), then smooth the disparity "
        "within each surface (edge-preserving domain transform, recursive, as RealSense's spatial filter): "
        "never across a depth edge, never into or out of a hole",
    )
    spatial_alpha: float = option(
        0.5, "Spatial filter: a pixel's own weight against its smoothed neighbour's (1 = no smoothing)", 0.05, 1.0
    )
    spatial_delta: float = option(
        2.0, "Spatial filter: a step between neighbours larger than this many px is a depth edge", 0.0, 64.0
    )
    spatial_iterations: int = option(2, "Spatial filter: passes over the image (a wider reach)", 1, 5, 1)
    spatial_outlier_radius: int = option(
        3,
        "Spatial filter: first a wrong match takes the median of the valid disparities within this many px, "
        "weighted by likeness in the image, so that a thin structure the image shows stays (0 = off)",
        0,
        5,
        1,
    )

    @property
    def temporal(self) -> TemporalSettings:
        return TemporalSettings(
            self.temporal_alpha,
            self.temporal_delta,
            self.temporal_persistence,
            self.temporal_history,
            self.temporal_motion_reset,
            self.temporal_presence,
            self.temporal_ego_motion,
        )

    @property
    def spatial(self) -> SpatialSettings:
        return SpatialSettings(
            self.spatial_alpha, self.spatial_delta, self.spatial_iterations, self.spatial_outlier_radius
        )

    def validate(self) -> StereoParams:
        """Refuse values that OpenCV would reject or silently change, with the reason."""
        checks: list[tuple[bool, str]] = [
            (
                self.disparity_range > 0 and self.disparity_range % 16 == 0,
                f"disparity_range {self.disparity_range} must be a positive multiple of 16",
            ),
            (
                self.correlation_window_size % 2 == 1,
                f"correlation_window_size {self.correlation_window_size} must be odd",
            ),
            (
                self.matcher != "bm" or self.correlation_window_size >= 5,
                f"correlation_window_size {self.correlation_window_size} is too small for bm (>= 5)",
            ),
            (self.prefilter_size % 2 == 1, f"prefilter_size {self.prefilter_size} must be odd"),
            (self.P2 > self.P1, f"P2 ({self.P2}) must be greater than P1 ({self.P1})"),
            (
                self.matcher != "census_sgm" or self.min_disparity >= 0,
                f"min_disparity {self.min_disparity} must be >= 0 for census_sgm (use sgbm for negative ones)",
            ),
            (self.downsample in (1, 2, 4), f"downsample {self.downsample} must be 1, 2 or 4"),
            (self.sgbm_mode in SGBM_MODES, f"sgbm_mode {self.sgbm_mode} must be one of {sorted(SGBM_MODES)}"),
        ]
        checks += [(False, reason) for reason in range_problems(self)]
        checks += self._cost_limits()  # after the ranges: those reasons come first
        for ok, reason in checks:
            if not ok:
                raise ParameterError(reason)
        self.temporal.validate()
        return self

    def _cost_limits(self) -> list[tuple[bool, str]]:
        """Settings each matcher's fixed-width arithmetic cannot hold, refused rather than silently wrapped.

        Measured on Middlebury Cones (test/test_core_accuracy.py sweeps every range's corners): past
        these limits OpenCV returns no or wrong disparities, or crashes the process.
        """
        window = self.correlation_window_size
        if self.matcher == "census_sgm":
            p2_limit = CENSUS_P2_PER_BIT * CENSUS_BITS * window * window
            return [
                (
                    p2_limit >= self.P2,  # (ruff reads the upper-case P2 as a constant)
                    f"P2 {self.P2:g} is above what census_sgm can honour with correlation_window_size {window}: "
                    f"at most {p2_limit} ({CENSUS_P2_PER_BIT} x {CENSUS_BITS} census bits x window area); "
                    "its 8-bit path costs would keep under 4 levels of matching cost beside such a P2",
                ),
                self._uniqueness_limit(),
            ]
        fixed_lo, fixed_hi = (self.min_disparity - 1) * 16, (self.min_disparity + self.disparity_range) * 16
        checks = [
            (
                fixed_lo >= -32768 and fixed_hi <= 32767,
                f"min_disparity {self.min_disparity} with disparity_range {self.disparity_range} leaves OpenCV's "
                "16-bit disparity (1/16 px steps, -2048..2047 px, one step below min_disparity for 'invalid'); "
                "keep min_disparity - 1 >= -2048 and min_disparity + disparity_range <= 2047",
            )
        ]
        if self.matcher == "bm":
            texture_limit = window * window * self.prefilter_cap
            checks.append(
                (
                    self.texture_threshold <= texture_limit,
                    f"texture_threshold {self.texture_threshold} is above what bm's window can reach: at most "
                    f"{texture_limit} (correlation_window_size {window} squared x prefilter_cap "
                    f"{self.prefilter_cap}, each prefiltered pixel at most prefilter_cap from its middle), so every "
                    "pixel would be invalid",
                )
            )
        if self.matcher == "sgbm":
            pixel_cost = 2 * self.prefilter_cap + 64  # Birchfield-Tomasi on the prefiltered + the raw image
            worst = pixel_cost * window * window + round(self.P2)
            checks += [
                (
                    worst <= SGBM_COST_MAX,
                    f"sgbm keeps costs in 16 bits: correlation_window_size {window} (x{pixel_cost} per pixel with "
                    f"prefilter_cap {self.prefilter_cap}) plus P2 {self.P2:g} reaches {worst} > {SGBM_COST_MAX}; "
                    "use a smaller window, P2 or prefilter_cap",
                ),
                self._uniqueness_limit(),
            ]
        return checks

    def _uniqueness_limit(self) -> tuple[bool, str]:
        """The semi-global matchers keep a pixel whose best cost is below (100 - ratio)% of every other
        disparity's (bm's ratio is a margin above the best instead, and 100 is a setting it honours)."""
        crash = ", and SGBM_3WAY stops the process with a floating-point exception" if self.matcher == "sgbm" else ""
        return (
            self.uniqueness_ratio < 100,
            f"uniqueness_ratio {self.uniqueness_ratio:g} must be below 100 for {self.matcher} (100 rejects every "
            f"pixel{crash})",
        )


# stereo_image_proc's defaults exactly (Jazzy disparity_node), for drop-in comparisons.
_STEREO_IMAGE_PROC: dict[str, Any] = {
    "matcher": "bm",
    "prefilter_size": 9,
    "prefilter_cap": 31,
    "correlation_window_size": 15,
    "min_disparity": 0,
    "disparity_range": 64,
    "texture_threshold": 10,
    "uniqueness_ratio": 15.0,
    "speckle_size": 100,
    "speckle_range": 4,
    "disp12_max_diff": 0,
    "P1": 200.0,
    "P2": 400.0,
    "sgbm_mode": 0,
    "near_detection": False,  # stereo_image_proc outputs too-near pixels as whatever the matcher gave
    "invalidate_saturated": False,
}

# The dataclass defaults are the recommended profile (semi-global, 3-way, small window, LR check).
PROFILES: dict[str, dict[str, Any]] = {
    "default": {},
    "stereo_image_proc": _STEREO_IMAGE_PROC,
    "fast": {
        "matcher": "bm",
        "correlation_window_size": 9,
        "uniqueness_ratio": 10.0,
        "texture_threshold": 5,
        "fill_holes": True,
        "hole_fill_radius": 0,
        "downsample": 2,
    },
    "quality": {
        "matcher": "census_sgm",
        "correlation_window_size": 1,
        "P1": 20.0,
        "P2": 200.0,
        "uniqueness_ratio": 3.0,
        "disp12_max_diff": 1,
        "speckle_range": 1,
        "confidence_threshold": 0.05,
    },
}

# Aliases kept for stereo_image_proc parameter files: they map onto our fields.
COMPAT_ALIASES = ("stereo_algorithm", "full_dp")


def field_names() -> list[str]:
    return option_names(StereoParams)


def translate_aliases(overrides: dict[str, Any]) -> dict[str, Any]:
    """Map stereo_image_proc's stereo_algorithm (0 BM, 1 SGBM) and full_dp onto matcher / sgbm_mode."""
    out = dict(overrides)
    if "stereo_algorithm" in out:
        algorithm = str(out.pop("stereo_algorithm")).strip()
        names = {"0": "bm", "1": "sgbm"}
        if algorithm not in names:
            msg = f"stereo_algorithm {algorithm} must be 0 (block matching) or 1 (semi-global)"
            raise ParameterError(msg)
        out.setdefault("matcher", names[algorithm])
    # full_dp parses like any bool field; true selects the full 8-path variant
    if "full_dp" in out and coerce("full_dp", out.pop("full_dp"), bool):
        out.setdefault("sgbm_mode", 1)
    return out


def make_params(profile: str = "default", overrides: dict[str, Any] | None = None) -> StereoParams:
    """The profile's values with `overrides` on top, validated; raises ParameterError with the reason."""
    if profile not in PROFILES:
        msg = f"profile '{profile}' is unknown; choose one of {sorted(PROFILES)}"
        raise ParameterError(msg)
    given = translate_aliases(overrides or {})
    for name in given:
        if name not in field_names():
            msg = f"unknown parameter '{name}'; known: {', '.join(field_names())}"
            raise ParameterError(msg)
    return StereoParams(**{**PROFILES[profile], **coerced(StereoParams, given)}).validate()


def parse_assignments(items: list[str]) -> dict[str, str]:
    """Parse CLI `name=value` items."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            msg = f"--set expects name=value, got '{item}'"
            raise ParameterError(msg)
        out[name.strip()] = value.strip()
    return out
