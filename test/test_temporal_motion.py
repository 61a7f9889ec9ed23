"""The temporal filter on a moving camera with odometry (core/temporal.py `CameraMotion`): the history moves
with the camera, so a still scene agrees with itself while the robot drives and turns."""

from __future__ import annotations

import cv2
import numpy as np

from stereo_depth.core.temporal import PRESENCE_RUN, CameraMotion, Projection, TemporalFilter, TemporalSettings

PERIOD_NS = 33_333_333
SETTINGS = TemporalSettings()
CALIBRATION = ("camera", 1)
HEIGHT, WIDTH = 120, 160
PROJECTION = Projection(200.0, 200.0, (WIDTH - 1) / 2.0, (HEIGHT - 1) / 2.0, 200.0 * 0.2, 0.0)
WALL_Z, BOX_Z = 4.0, 2.0  # m, in the first camera's frame: a wall, and a box in front of it
BOX = (-0.3, 0.3, -0.25, 0.25)  # its front face's x and y extent


def camera_pose(k: int) -> np.ndarray:
    """The camera after k frames: turned 0.5 degrees a frame about its y axis, 2 cm a frame to the right."""
    angle = np.radians(0.5 * k)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
    pose[0, 3] = 0.02 * k
    return pose


def true_disparity(pose: np.ndarray) -> np.ndarray:
    """The scene seen from `pose`: each pixel's ray cast on the box's face and the wall, the nearest hit."""
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    rays = np.stack([(u - PROJECTION.cx) / PROJECTION.fx, (v - PROJECTION.cy) / PROJECTION.fy, np.ones_like(u)], -1)
    directions = rays @ pose[:3, :3].T  # in the first camera's frame; a ray's camera depth is its parameter
    origin = pose[:3, 3]
    wall = (WALL_Z - origin[2]) / directions[..., 2]
    box = (BOX_Z - origin[2]) / directions[..., 2]
    hit = origin + box[..., None] * directions
    on_box = (hit[..., 0] >= BOX[0]) & (hit[..., 0] <= BOX[1]) & (hit[..., 1] >= BOX[2]) & (hit[..., 1] <= BOX[3])
    depth = np.where(on_box, box, wall)
    disparity: np.ndarray = (PROJECTION.fb / depth).astype(np.float32)
    return disparity


def noisy(truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A matcher's output: noise, holes in 10 % of the pixels and wrong values in 3 %, fresh each frame."""
    d = truth + rng.normal(0.0, 0.3, truth.shape).astype(np.float32)
    d[rng.random(d.shape) < 0.03] = rng.uniform(5.0, 30.0)
    d[rng.random(d.shape) < 0.1] = np.nan
    return d


def drive(frames: int, motion: bool, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The filter's outputs and the truths of a camera driving past the box, with or without odometry."""
    rng = np.random.default_rng(seed)
    temporal = TemporalFilter()
    outs, truths = [], []
    for k in range(frames):
        truth = true_disparity(camera_pose(k))
        given = CameraMotion(camera_pose(k), PROJECTION) if motion else None
        outs.append(temporal.apply(noisy(truth, rng), None, k * PERIOD_NS, CALIBRATION, SETTINGS, motion=given))
        truths.append(truth)
    return outs, truths


def scores(out: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Density, and the share of the output more than 1 px off."""
    valid = np.isfinite(out)
    return float(valid.mean()), float((np.abs(out - truth)[valid] > 1.0).mean())


def test_with_odometry_a_still_scene_stays_dense_and_right_while_the_camera_moves() -> None:
    """16 frames driving and turning (8 degrees, 32 cm; the view slides 3.5 px a frame): with odometry
    the history moves with it, the box stays in front of the wall and the wrong values never pass;
    without it the history under a pixel is another part of the scene, and wrong values pass."""
    outs, truths = drive(16, motion=True)
    for out, truth in zip(outs[8:], truths[8:], strict=True):
        density, wrong = scores(out, truth)
        assert density > 0.85 and wrong < 0.003
        box = cv2.erode((truth > 15.0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # 2 px from its edges
        assert (out[box] < 15.0).sum() == 0  # the nearer surface wins where both land: no wall on the box
    unmoved, _ = drive(16, motion=False)
    assert all(scores(out, truth)[1] > 0.01 for out, truth in zip(unmoved[8:], truths[8:], strict=True))


def test_a_parked_robot_with_odometry_gives_exactly_what_no_odometry_gives() -> None:
    rng = np.random.default_rng(2)
    truth = true_disparity(np.eye(4))
    frames = [noisy(truth, rng) for _ in range(12)]
    with_odometry, without = TemporalFilter(), TemporalFilter()
    for k, d in enumerate(frames):
        parked = camera_pose(5)  # anywhere, with the jitter of a parked robot's odometry: 0.1 mm
        parked[:3, 3] += rng.normal(0.0, 1e-4, 3)
        a = with_odometry.apply(d, None, k * PERIOD_NS, CALIBRATION, SETTINGS, motion=CameraMotion(parked, PROJECTION))
        b = without.apply(d, None, k * PERIOD_NS, CALIBRATION, SETTINGS)
        np.testing.assert_array_equal(a, b)


def test_odometry_that_stopped_or_jumped_restarts_the_history() -> None:
    truth = true_disparity(np.eye(4))
    temporal = TemporalFilter()
    outs = []
    for k in range(8):
        motion = CameraMotion(None if k == 6 else np.eye(4), PROJECTION, forget=k == 6)
        outs.append(temporal.apply(truth, None, k * PERIOD_NS, CALIBRATION, SETTINGS, motion=motion))
    assert np.isfinite(outs[5]).all()
    assert np.isnan(outs[6]).all() and np.isnan(outs[7]).all()  # a new history: persistence not yet met


def test_the_image_test_stands_down_while_odometry_explains_the_motion() -> None:
    """The view slides 3 px a frame. With the poses that explain it, the filter keeps filtering; a frame
    whose pose is unknown (its odometry late) falls back to the image test, which stands aside."""
    rng = np.random.default_rng(5)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (HEIGHT * 4, WIDTH * 4)).astype(np.uint8), (5, 5), 0)
    slide = np.eye(4)
    explained, unexplained = TemporalFilter(), TemporalFilter()
    for k in range(10):
        slide[1, 3] = -3.0 * k / PROJECTION.fy * 4.0  # the camera moves up: the wall slides down 3 px
        truth = np.full((HEIGHT, WIDTH), 10.0, np.float32) + np.float32(0.1 * (k % 2))
        view = np.roll(texture, 3 * 4 * k, axis=0)
        a = explained.apply(
            truth, None, k * PERIOD_NS, CALIBRATION, SETTINGS, view=view, motion=CameraMotion(slide.copy(), PROJECTION)
        )
        b = unexplained.apply(
            truth, None, k * PERIOD_NS, CALIBRATION, SETTINGS, view=view, motion=CameraMotion(None, PROJECTION)
        )
    assert not np.array_equal(a, truth) and np.isfinite(a[24:]).all()  # filtered (the rows entering the view: not yet)
    np.testing.assert_array_equal(b, truth)  # standing aside: the matcher's disparity as it is


def test_where_a_moved_frame_lands_two_surfaces_on_a_pixel_the_nearer_one_wins() -> None:
    """Five frames still, then the camera steps 10 cm to the left: the box slides 5 px further than the
    wall and hides a band of the wall the history saw. Moved into the new view, each remembered frame
    keeps the box there, so the box's pixels keep their support."""
    temporal = TemporalFilter()
    poses = [np.eye(4)] * 5 + [np.eye(4)]
    poses[-1] = poses[-1].copy()
    poses[-1][0, 3] = -0.1
    for k, pose in enumerate(poses):
        truth = true_disparity(pose)
        out = temporal.apply(truth, None, k * PERIOD_NS, CALIBRATION, SETTINGS, motion=CameraMotion(pose, PROJECTION))
    box = cv2.erode((truth > 15.0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    np.testing.assert_allclose(out[box], truth[box], atol=0.1)


def test_after_the_robot_moves_presence_counts_the_frames_of_the_new_view_only() -> None:
    """Parked for PRESENCE_RUN frames before a wall whose left part is textureless (holes), then 16
    frames driving and turning right, then parked again: the textured wall now under the pixels that
    saw the holes is output as soon as the new view's frames allow, not held back by the holes the
    still view counted there."""
    rng = np.random.default_rng(7)
    poses = [np.eye(4)] * PRESENCE_RUN + [camera_pose(k) for k in range(1, 17)] + [camera_pose(16)] * 12
    temporal = TemporalFilter()
    for k, pose in enumerate(poses):
        d = noisy(true_disparity(pose), rng)
        d[wall_x(pose) < WALL_HOLES] = np.nan
        out = temporal.apply(d, None, k * PERIOD_NS, CALIBRATION, SETTINGS, motion=CameraMotion(pose, PROJECTION))
    saw_holes = wall_x(np.eye(4)) < WALL_HOLES
    textured_now = wall_x(poses[-1]) >= WALL_HOLES
    assert (saw_holes & textured_now).sum() > 1000
    assert np.isfinite(out[saw_holes & textured_now]).mean() > 0.8


WALL_HOLES = -0.7  # m: the wall is textureless left of this x (the matcher finds nothing there)


def wall_x(pose: np.ndarray) -> np.ndarray:
    """Where each pixel's ray meets the wall: x in the first camera's frame, m."""
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    rays = np.stack([(u - PROJECTION.cx) / PROJECTION.fx, (v - PROJECTION.cy) / PROJECTION.fy, np.ones_like(u)], -1)
    directions = rays @ pose[:3, :3].T
    along = (WALL_Z - pose[2, 3]) / directions[..., 2]
    x: np.ndarray = pose[0, 3] + along * directions[..., 0]
    return x
