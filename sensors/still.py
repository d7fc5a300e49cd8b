"""Ground truth of a robot body held still: the state of long still-IMU records (Allan deviation)
and of the sensor cost benchmark."""

from __future__ import annotations

import numpy as np

from testbed.model.truth import NUM_JOINTS, NUM_LEGS, Truth


def still_truth(t: float = 0.0, rotation: np.ndarray | None = None, foot_force: float = 0.0) -> Truth:
    """At rest at time t with body orientation `rotation` (world_from_body), each foot pressing foot_force N."""
    zero = np.zeros(3)
    forces = np.full(NUM_LEGS, foot_force)
    return Truth(t=t, body_position=zero, body_rotation=np.eye(3) if rotation is None else rotation,
                 body_linear_velocity=zero, body_angular_velocity=zero, body_linear_acceleration=zero,
                 body_angular_acceleration=zero, joint_positions=np.zeros(NUM_JOINTS),
                 joint_velocities=np.zeros(NUM_JOINTS), foot_positions=np.zeros((NUM_LEGS, 3)),
                 foot_forces=np.zeros((NUM_LEGS, 3)), foot_normal_forces=forces, foot_contact=forces > 0,
                 com_position=zero)
