import math

import numpy as np
import pytest
from numba import njit
from scipy.spatial.transform import Rotation

from testbed.model import spatial as rot

RNG = np.random.default_rng(4)
ROTATIONS = Rotation.random(50, random_state=5)


def test_quaternions_are_scipy_ordered_world_from_body():
    for r in ROTATIONS:
        q = tuple(r.as_quat())
        assert np.allclose(rot.to_matrix(q), r.as_matrix(), atol=1e-12)
        yaw, pitch, roll = r.as_euler("ZYX")
        assert np.allclose(rot.euler_from_quaternion(q), (roll, pitch, yaw), atol=1e-9)
        assert np.allclose(rot.to_matrix(rot.quaternion_from_euler(roll, pitch, yaw)), r.as_matrix(), atol=1e-12)


def test_up_in_body_is_third_row():
    for r in ROTATIONS:
        assert np.allclose(rot.up_in_body(tuple(r.as_quat())), r.as_matrix()[2], atol=1e-12)


def test_exp_log_and_local_perturbation():
    for vector in RNG.uniform(-1.5, 1.5, (20, 3)):    # angles below pi: one rotation vector each
        q = rot.exp(*vector)
        assert np.allclose(Rotation.from_quat(q).as_rotvec(), vector, atol=1e-12)
        assert np.allclose(rot.log(q), vector, atol=1e-12)
    base = tuple(ROTATIONS[0].as_quat())
    turned = rot.rotate_by_vector(base, 0.1, -0.2, 0.3)
    expected = ROTATIONS[0] * Rotation.from_rotvec([0.1, -0.2, 0.3])
    assert np.allclose(rot.to_matrix(turned), expected.as_matrix(), atol=1e-12)


def test_skew_is_the_cross_product_matrix():
    a, b = RNG.normal(size=3), RNG.normal(size=3)
    np.testing.assert_allclose(rot.skew(a) @ b, np.cross(a, b), rtol=0, atol=1e-15)
    np.testing.assert_allclose(rot.skew(tuple(a)), rot.skew(a), rtol=0, atol=0)


def test_quaternion_from_matrix_inverts_to_matrix():
    for r in ROTATIONS:
        q = rot.quaternion_from_matrix(r.as_matrix())
        assert q[3] >= 0
        np.testing.assert_allclose(q, r.as_quat(canonical=True), rtol=0, atol=1e-12)
    half_turn = Rotation.from_rotvec([0.0, np.pi, 0.0]).as_matrix()      # trace -1: the other branch
    np.testing.assert_allclose(rot.to_matrix(rot.quaternion_from_matrix(half_turn)), half_turn, atol=1e-12)


def test_wrap_angle_to_minus_pi_pi():
    angles = np.array([-7.0, -math.pi, -1.0, 0.0, 1.0, math.pi, 7.0])
    wrapped = rot.wrap_angle(angles)
    assert np.all((wrapped >= -math.pi) & (wrapped < math.pi))
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    np.testing.assert_allclose(np.sin(wrapped), np.sin(angles), atol=1e-12)
    assert rot.wrap_angle(7.0) == pytest.approx(7.0 - 2 * math.pi)


def test_compiled_helpers_equal_the_python_ones():
    """The helpers run as Python and compiled into kernels: the same numbers either way."""
    compiled = njit(lambda q, v: (rot.to_matrix(q), rot.log(q), rot.euler_from_quaternion(q),
                                  rot.rotate_by_vector(q, v[0], v[1], v[2]), rot.skew(v),
                                  rot.quaternion_from_matrix(rot.to_matrix(q))))
    for r in ROTATIONS[:10]:
        q, v = tuple(r.as_quat()), RNG.normal(size=3)
        python = (rot.to_matrix(q), rot.log(q), rot.euler_from_quaternion(q), rot.rotate_by_vector(q, *v),
                  rot.skew(v), rot.quaternion_from_matrix(rot.to_matrix(q)))
        for mine, theirs in zip(compiled(q, v), python):
            np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-15)


def test_euler_jacobian_matches_finite_differences():
    q = rot.quaternion_from_euler(0.3, -0.4, 1.0)
    jacobian = rot.euler_jacobian(0.3, -0.4)
    step = 1e-7
    for axis in range(3):
        delta = np.zeros(3)
        delta[axis] = step
        moved = np.array(rot.euler_from_quaternion(rot.rotate_by_vector(q, *delta)))
        assert np.allclose((moved - rot.euler_from_quaternion(q)) / step, jacobian[:, axis], atol=1e-5)
    # Roll and pitch do not see a rotation about the vertical: yaw variance cannot leak into them.
    assert np.allclose(jacobian[:2] @ rot.up_in_body(q), 0.0, atol=1e-12)


def test_euler_jacobian_stays_finite_at_gimbal_lock():
    assert np.isfinite(rot.euler_jacobian(0.2, math.pi / 2)).all()


def test_tilt_from_specific_force_at_rest():
    for r in ROTATIONS:
        yaw, pitch, roll = r.as_euler("ZYX")
        force = 9.81 * r.as_matrix()[2]
        assert np.allclose(rot.tilt_from_specific_force(*force), (roll, pitch), atol=1e-9)


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0)])
def test_normalising_a_degenerate_quaternion_gives_identity(q):
    assert rot.normalized(q) == rot.IDENTITY
