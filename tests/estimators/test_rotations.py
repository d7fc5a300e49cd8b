import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimators import linalg
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


def test_batch_versions_match_scalar_ones():
    vectors = RNG.uniform(-1.5, 1.5, (10, 3))
    vectors[0] = 0.0
    quats = rot.exp_batch(vectors)
    assert np.allclose(quats, [rot.exp(*v) for v in vectors], atol=1e-14)
    others = np.array([rot.exp(*v) for v in RNG.normal(0.0, 1.0, (10, 3))])
    assert np.allclose(rot.multiply_batch(quats, others), [rot.multiply(tuple(p), tuple(q)) for p, q in zip(quats, others)])
    assert np.allclose(rot.log_batch(quats), vectors, atol=1e-12)
    assert np.allclose(rot.to_matrix_batch(quats), [rot.to_matrix(tuple(q)) for q in quats])


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


def test_small_linear_algebra():
    matrix = RNG.normal(size=(3, 3)) + 3 * np.eye(3)
    assert np.allclose(linalg.inverse3(matrix), np.linalg.inv(matrix))
    a, b = RNG.normal(size=3), RNG.normal(size=3)
    assert np.allclose(linalg.cross(a, b), np.cross(a, b))
    assert np.allclose(linalg.skew(a) @ b, np.cross(a, b))
    vectors = RNG.normal(size=(6, 3))
    assert np.allclose(linalg.stacked_skew(vectors), np.vstack([linalg.skew(v) for v in vectors]))
    assert linalg.stacked_skew(vectors[:2]).shape == (6, 3)


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0)])
def test_normalising_a_degenerate_quaternion_gives_identity(q):
    assert rot.normalized(q) == rot.IDENTITY
