"""The state read-out: everything the truth and the contact models need, from DART's coordinates.

DART's generalized coordinates hold the root FreeJoint's six first (rotation vector, then
translation; its rates: angular, then linear velocity), then the joints' eighteen. The body's pose
and twist follow from the root joint's as DART computes them (`free_joint_transform`,
`free_joint_twist`; tests/testbed/test_simulation_state.py compares them with DART's getters), which
holds for a FreeJoint to the world with identity offsets (`Simulation._check_root_joint`); the feet
and tibias follow by eq. 2 (kinematics.world_feet_of). One compiled call per physics step
(`read_out`) returns them as one STATE record, whose fields the truth's arrays are views of.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from testbed.model.kinematics import LegGeometry, world_feet_of
from testbed.model.spatial import quaternion_from_matrix
from testbed.world.records import one_record, the_record

LEGS = 6
ROOT_ROTATION, ROOT_TRANSLATION, ROOT_DOFS = slice(0, 3), slice(3, 6), 6
ANGULAR, LINEAR = slice(0, 3), slice(3, 6)      # the parts of DART's spatial velocities (twists)
EXP_MAP_SMALL_ANGLE = 1e-3      # rad: DART's expMapRot switches to its second-order series below this

# The read-out of one step, a 0-d array (new at each step: the truth's arrays are views of it): the
# body's pose, its world-frame velocities and their finite differences over the step, its attitude
# as (x, y, z, w), the feet and tibias by eq. 2 (kinematics.WorldFeet's arrays), and the contact a
# model computes from this state in the same call (FootContacts' arrays; zeros for other models).
STATE = np.dtype([("rotation", np.float64, (3, 3)), ("position", np.float64, (3,)),
                  ("linear_velocity", np.float64, (3,)), ("angular_velocity", np.float64, (3,)),
                  ("linear_acceleration", np.float64, (3,)), ("angular_acceleration", np.float64, (3,)),
                  ("quaternion", np.float64, (4,)), ("foot_centers", np.float64, (LEGS, 3)),
                  ("foot_velocities", np.float64, (LEGS, 3)), ("tibia_spins", np.float64, (LEGS, 3)),
                  ("tibia_rotations", np.float64, (LEGS, 3, 3)), ("tibia_origins", np.float64, (LEGS, 3)),
                  ("contact_forces", np.float64, (LEGS, 3)), ("contact_normal_forces", np.float64, (LEGS,)),
                  ("contact_normals", np.float64, (LEGS, 3)), ("contact_points", np.float64, (LEGS, 3))])
# What the read-out needs besides DART's coordinates: the time step, the leg geometry, and the
# body's velocities one step earlier (updated in place).
READ_OUT = np.dtype([("dt", np.float64), ("femur", np.float64), ("tibia", np.float64),
                     ("base_angle", np.float64, (LEGS,)), ("base_distance", np.float64, (LEGS,)),
                     ("previous_linear_velocity", np.float64, (3,)), ("previous_angular_velocity", np.float64, (3,))])


def read_out_record(dt: float, geometry: LegGeometry) -> np.ndarray:
    """A one-element READ_OUT array for a body at rest."""
    return one_record(READ_OUT, dt=dt, femur=geometry.femur, tibia=geometry.tibia, base_angle=geometry.base_angle,
                      base_distance=geometry.base_distance, previous_linear_velocity=0.0, previous_angular_velocity=0.0)


@njit(cache=True)
def read_out(positions, velocities, read_out_raw):
    """The 0-d STATE array of DART's coordinates and rates `positions`, `velocities` with the READ_OUT
    record `read_out_raw` (its bytes; its previous velocities updated in place); whether every
    coordinate and rate is finite; and the body's z axis's vertical component (world_from_body[2, 2])."""
    state = np.zeros((), STATE)
    finite, up = read_out_into(positions, velocities, the_record(read_out_raw.view(READ_OUT)), state[()])
    return state, finite, up


@njit(cache=True)
def read_out_into(positions, velocities, settings, out):
    """`read_out` into the STATE record `out`, with the READ_OUT record `settings`."""
    transform = free_joint_transform(positions)
    rotation = transform[:3, :3]
    twist = free_joint_twist(rotation, velocities)
    body_angular, body_linear = twist[ANGULAR], twist[LINEAR]
    for i in range(3):
        angular = rotation[i, 0] * body_angular[0] + rotation[i, 1] * body_angular[1] + rotation[i, 2] * body_angular[2]
        linear = rotation[i, 0] * body_linear[0] + rotation[i, 1] * body_linear[1] + rotation[i, 2] * body_linear[2]
        # Finite differences of the body velocity over the step: DART's own accelerations miss the
        # servo and contact constraint impulses, which are part of what an accelerometer feels.
        out.linear_acceleration[i] = (linear - settings.previous_linear_velocity[i]) / settings.dt
        out.angular_acceleration[i] = (angular - settings.previous_angular_velocity[i]) / settings.dt
        out.linear_velocity[i], out.angular_velocity[i], out.position[i] = linear, angular, transform[i, 3]
        for j in range(3):
            out.rotation[i, j] = rotation[i, j]
    settings.previous_linear_velocity[:] = out.linear_velocity
    settings.previous_angular_velocity[:] = out.angular_velocity
    x, y, z, w = quaternion_from_matrix(rotation)
    out.quaternion[0], out.quaternion[1], out.quaternion[2], out.quaternion[3] = x, y, z, w
    if not (np.isfinite(positions).all() and np.isfinite(velocities).all()):
        return False, rotation[2, 2]
    centers, feet_velocities, spins, rotations, origins = world_feet_of(
        rotation, out.position, out.angular_velocity, out.linear_velocity, positions[ROOT_DOFS:],
        velocities[ROOT_DOFS:], settings)
    out.foot_centers[:] = centers
    out.foot_velocities[:] = feet_velocities
    out.tibia_spins[:] = spins
    out.tibia_rotations[:] = rotations
    out.tibia_origins[:] = origins
    return True, rotation[2, 2]


@njit(cache=True)
def free_joint_transform(positions):
    """(4, 4) world_from_body of the root FreeJoint's coordinates (rotation vector, translation): DART's
    math::expMapRot, R = I + sin(t)/t [q]x + (1 - cos(t))/t^2 [q]x^2 (I + [q]x + [q]x^2 / 2 below the
    small angle), in Eigen's order of operations; the translation gains DART's + 0.0 (-0.0 becomes 0.0)."""
    rotation_vector, translation = positions[ROOT_ROTATION], positions[ROOT_TRANSLATION]
    q0, q1, q2 = rotation_vector[0], rotation_vector[1], rotation_vector[2]
    theta = math.sqrt((q0 * q0 + q1 * q1) + q2 * q2)
    if theta < EXP_MAP_SMALL_ANGLE:
        first, second = 1.0, 0.5
    else:
        first, second = math.sin(theta) / theta, (1.0 - math.cos(theta)) / (theta * theta)
    hat = np.array([[0.0, -q2, q1], [q2, 0.0, -q0], [-q1, q0, 0.0]])
    transform = np.zeros((4, 4))
    for i in range(3):
        for j in range(3):
            squared = (hat[i, 0] * hat[0, j] + hat[i, 1] * hat[1, j]) + hat[i, 2] * hat[2, j]
            transform[i, j] = ((1.0 if i == j else 0.0) + first * hat[i, j]) + second * squared
        transform[i, 3] = translation[i] + 0.0
    transform[3, 3] = 1.0
    return transform


@njit(cache=True)
def free_joint_twist(rotation, velocities):
    """(6,) body-frame spatial velocity (angular, linear) of the root FreeJoint's rates (world frame):
    R^T w and R^T v, summed onto 0.0 as DART accumulates them onto a zero twist (-0.0 becomes 0.0)."""
    twist = np.empty(6)
    for part in (ANGULAR, LINEAR):
        rate, body = velocities[part], twist[part]
        for i in range(3):
            body[i] = 0.0 + ((rotation[0, i] * rate[0] + rotation[1, i] * rate[1]) + rotation[2, i] * rate[2])
    return twist


