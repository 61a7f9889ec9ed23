"""The pose type that pose options are read into: `[x, y, z, qx, qy, qz, qw]`, seven zeros for "not given"."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereo_depth.core.pose import UNSET_POSE, Pose
from stereo_depth.errors import ParameterError

HALF = math.sqrt(0.5)
TURN_Z = Pose.from_list([1.0, 2.0, 3.0, 0.0, 0.0, HALF, HALF])  # 90 degrees about z, then moved
TILT_X = Pose.from_list([0.0, -0.5, 0.25, math.sin(0.2), 0.0, 0.0, math.cos(0.2)])  # 0.4 rad about x


def test_a_quarter_turn_about_z_takes_x_to_y_then_moves() -> None:
    assert TURN_Z.apply(np.array([1.0, 0.0, 0.0])) == pytest.approx([1.0, 3.0, 3.0])
    rotation = TURN_Z.rotation_matrix()
    assert rotation @ rotation.T == pytest.approx(np.eye(3))


def test_composing_applies_the_inner_pose_first_and_the_inverse_undoes_it() -> None:
    points = np.array([[0.3, -1.0, 2.0], [5.0, 0.1, -0.2]])
    assert TURN_Z.compose(TILT_X).apply(points) == pytest.approx(TURN_Z.apply(TILT_X.apply(points)))
    assert TURN_Z.inverse().apply(TURN_Z.apply(points)) == pytest.approx(points)
    identity = TURN_Z.compose(TURN_Z.inverse())
    assert identity.translation == pytest.approx((0, 0, 0), abs=1e-12)
    assert abs(identity.rotation[3]) == pytest.approx(1.0)


def test_seven_zeros_are_unset_and_have_no_rotation() -> None:
    unset = Pose.from_list([0, 0, 0, 0, 0, 0, 0])
    assert unset == UNSET_POSE and not unset.is_set and TURN_Z.is_set
    with pytest.raises(ValueError, match="unset pose has no rotation"):
        unset.rotation_matrix()


def test_a_nearly_unit_quaternion_is_normalised_and_a_farther_one_refused_with_its_norm() -> None:
    near = Pose.from_list([0, 0, 0, 0, 0, 0, 1.0009])
    assert near.rotation == (0.0, 0.0, 0.0, 1.0)
    with pytest.raises(ParameterError, match=r"quaternion \(0, 0, 0, 1.0011\) has norm 1.0011; give a unit"):
        Pose.from_list([0, 0, 0, 0, 0, 0, 1.0011])
    with pytest.raises(ParameterError, match=r"quaternion \(0, 0, 0, 0\) has norm 0.0000"):
        Pose.from_list([1.0, 0, 0, 0, 0, 0, 0])  # a translation without a rotation is not "unset"
    with pytest.raises(ParameterError, match=r"a pose has 7 values \(x, y, z, qx, qy, qz, qw\), got 6"):
        Pose.from_list([0, 0, 0, 0, 0, 1])
