"""The anchor's synthetic stereo stream, rendered in Python: the same recipe as the ROS 1 stereo_image_proc
anchor's make_bag.py (bench/e2e_dds.py --anchor DIR), so our figures and stereo_image_proc's come from the
same kind of frames (mono8, fx = fy = 500, cx = W/2, cy = H/2, no distortion, baseline 0.1 m,
textured fronto-parallel layers at disparities 6 / 20 / 35 / 50 px that slide sideways over time).

Same seed, same random draws in the same order: the frames equal the anchor bag's except for one grey level
on about 1e-5 of the pixels (NumPy 2 rounds a float32 step differently from Debian's NumPy 1.24).
Imported by the bench scripts; not a test fixture and not part of the package.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from stereo_depth.core.camera import CameraInfo

FRAME_ID = "stereo_optical_frame"  # one frame_id for both cameras, as the anchor's bag
BACKGROUND_DISPARITY = 6
PAN_PX_PER_FRAME = 0.3
# (disparity px, x0, y0, w, h at 640x480, vx px/frame, mean brightness); far to near
BOXES = (
    (20, 60, 70, 260, 220, 0.5, 110),
    (35, 330, 180, 220, 200, -0.7, 150),
    (50, 150, 300, 150, 140, 1.0, 90),
)


def texture(rng: np.random.Generator, height: int, width: int, mean: float) -> np.ndarray:
    """Band-limited random texture (noise smoothed by a 3x3 box), uint8-range float."""
    noise = rng.integers(0, 256, size=(height + 2, width + 2)).astype(np.float32)
    window_sum = sum(noise[dy : dy + height, dx : dx + width] for dy in range(3) for dx in range(3))
    smooth = np.asarray(window_sum, dtype=np.float32) / 9.0
    smooth = (smooth - smooth.mean()) / (smooth.std() + 1e-6)
    return np.asarray(np.clip(mean + 45.0 * smooth, 0, 255), dtype=np.float32)


def paste(image: np.ndarray, patch: np.ndarray, x0: int, y0: int) -> None:
    """Paste patch at (x0, y0) into image, clipped to the image bounds."""
    height, width = image.shape
    h, w = patch.shape
    xa, xb = max(x0, 0), min(x0 + w, width)
    ya, yb = max(y0, 0), min(y0 + h, height)
    if xa < xb and ya < yb:
        image[ya:yb, xa:xb] = patch[ya - y0 : yb - y0, xa - x0 : xb - x0]


def camera_infos(width: int, height: int, fx: float = 500.0, baseline: float = 0.1) -> tuple[CameraInfo, CameraInfo]:
    """Left and right calibration: identical intrinsics, P_right[0, 3] = -fx * baseline."""
    k = [fx, 0.0, width / 2.0, 0.0, fx, height / 2.0, 0.0, 0.0, 1.0]
    r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]

    def info(tx: float) -> CameraInfo:
        p = [fx, 0.0, width / 2.0, tx, 0.0, fx, height / 2.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        return CameraInfo.from_values(width, height, k, [0.0] * 5, r, p, "plumb_bob", FRAME_ID)

    return info(0.0), info(-fx * baseline)


@dataclass
class _Layer:
    disparity: int
    x0: int
    y0: int
    texture: np.ndarray
    vx: float


def frames(
    width: int = 640, height: int = 480, count: int = 300, seed: int = 1
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(left, right) uint8 pairs; a point at left column x appears at x - d in the right view."""
    sx, sy = width / 640.0, height / 480.0
    rng = np.random.default_rng(seed)
    background = texture(rng, height, width + 64 + int(PAN_PX_PER_FRAME * count) + 8, 128)
    layers = [
        _Layer(d, int(x0 * sx), int(y0 * sy), texture(rng, int(h * sy), int(w * sx), mean), vx)
        for d, x0, y0, w, h, vx, mean in BOXES
    ]

    def render(i: int, right: bool) -> np.ndarray:
        pan = int(PAN_PX_PER_FRAME * i)
        offset = BACKGROUND_DISPARITY if right else 0
        image = background[:, pan + offset : pan + offset + width].copy()
        for layer in layers:
            x = layer.x0 + round(layer.vx * i)
            paste(image, layer.texture, x - (layer.disparity if right else 0), layer.y0)
        image += rng.normal(0.0, 2.0, size=image.shape).astype(np.float32)  # sensor noise
        return np.asarray(np.clip(image, 0, 255), dtype=np.uint8)

    for i in range(count):
        left = render(i, False)
        yield left, render(i, True)
