"""Ground truth of one physics step.

The simulation produces it; sensors, the recorder and the metrics read it. Estimators and
controllers never see it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

NUM_LEGS = 6
JOINTS_PER_LEG = 3
NUM_JOINTS = NUM_LEGS * JOINTS_PER_LEG


class Truth(NamedTuple):
    """Immutable like every record of the run loop; a named tuple because one is built per physics
    step, and a frozen dataclass's __init__ (a setattr call per field) costs twice as much."""
    t: float                                  # s, simulation time
    body_position: np.ndarray                 # (3,) m, world: body origin O_b (the main body's centre of mass)
    body_rotation: np.ndarray                 # (3, 3) rotation world_from_body
    body_linear_velocity: np.ndarray          # (3,) m/s, world, of O_b
    body_angular_velocity: np.ndarray         # (3,) rad/s, world
    body_linear_acceleration: np.ndarray      # (3,) m/s^2, world, classical acceleration of O_b
    body_angular_acceleration: np.ndarray     # (3,) rad/s^2, world
    joint_positions: np.ndarray               # (18,) rad, leg-major: leg 1 joints 1..3, leg 2, ...
    joint_velocities: np.ndarray              # (18,) rad/s
    foot_positions: np.ndarray                # (6, 3) m, world: foot sphere centres
    foot_forces: np.ndarray                   # (6, 3) N, world: ground reaction force on each foot
    foot_normal_forces: np.ndarray            # (6,) N, component along the terrain normal (>= 0)
    foot_contact: np.ndarray                  # (6,) bool, foot touches the ground
    com_position: np.ndarray                  # (3,) m, world: whole-robot centre of mass
