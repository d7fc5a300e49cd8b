"""The robot description: a URDF generated from the config, the one description of the robot.

19 links (body, and coxa/femur/tibia for each of the 6 legs), 18 revolute joints. Link frames are
placed on the Denavit-Hartenberg frames of the paper's section 3.1, so that the URDF's forward
kinematics equals eq. 2: the coxa link turns about z_0i; the femur and tibia links have their
x axis along the link and their z axis on the joint axis (z_1i = z_2i); the foot sphere centre
is at x = a3 on the tibia link (the DH frame O_3i).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from xml.sax.saxutils import escape

import numpy as np

from testbed.model.robot_config import RobotConfig
from testbed.model.kinematics import LegGeometry

LEG_NAMES = ("leg1", "leg2", "leg3", "leg4", "leg5", "leg6")
LINKS_PER_LEG = ("coxa", "femur", "tibia")


@dataclass(frozen=True)
class Inertia:
    mass: float
    com: tuple[float, float, float]
    diagonal: tuple[float, float, float]   # kg m^2 about the centre of mass, link axes


def box_inertia(mass: float, size: tuple[float, ...], com=(0.0, 0.0, 0.0)) -> Inertia:
    x, y, z = size
    return Inertia(mass, tuple(com), (mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12,
                                      mass * (x * x + y * y) / 12))


def rod_inertia(mass: float, radius: float, length: float) -> Inertia:
    """Solid cylinder along x from 0 to `length`."""
    axial = mass * radius * radius / 2
    transverse = mass * (3 * radius * radius + length * length) / 12
    return Inertia(mass, (length / 2, 0.0, 0.0), (axial, transverse, transverse))


def link_inertias(robot: RobotConfig) -> dict[str, Inertia]:
    """Inertia of each link type from its geometry (uniform density boxes and rods)."""
    femur_box = (robot.femur_length, robot.femur_section[1], robot.femur_section[0])
    return {
        "body": box_inertia(robot.body_mass, robot.body_size),
        "coxa": box_inertia(robot.coxa_mass, robot.coxa_size),
        "femur": box_inertia(robot.femur_mass, femur_box, (robot.femur_length / 2, 0.0, 0.0)),
        "tibia": rod_inertia(robot.tibia_mass, robot.tibia_radius, robot.tibia_length),
    }


def total_mass(robot: RobotConfig) -> float:
    return robot.body_mass + 6 * (robot.coxa_mass + robot.femur_mass + robot.tibia_mass)


def _vec(values) -> str:
    return " ".join(repr(float(v)) for v in values)   # shortest exact decimal: FK agrees to 1e-15


def _inertial(inertia: Inertia) -> str:
    ixx, iyy, izz = inertia.diagonal
    return (f'<inertial><origin xyz="{_vec(inertia.com)}" rpy="0 0 0"/><mass value="{inertia.mass:.17g}"/>'
            f'<inertia ixx="{ixx:.17g}" ixy="0" ixz="0" iyy="{iyy:.17g}" iyz="0" izz="{izz:.17g}"/></inertial>')


def _geometry_block(tag: str, geometry: str, xyz=(0, 0, 0), rpy=(0, 0, 0), material: str = "") -> str:
    return f'<{tag}><origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/><geometry>{geometry}</geometry>{material}</{tag}>'


def _link(name: str, inertia: Inertia, visuals: list[str], collisions: list[str]) -> str:
    return f'  <link name="{escape(name)}">{_inertial(inertia)}{"".join(visuals)}{"".join(collisions)}</link>'


def _joint(name: str, parent: str, child: str, xyz, rpy, lower: float, upper: float, robot: RobotConfig) -> str:
    return (f'  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/><axis xyz="0 0 1"/>'
            f'<limit lower="{lower:.17g}" upper="{upper:.17g}" effort="{robot.servo_torque_limit:.17g}" '
            f'velocity="{robot.servo_speed_limit:.17g}"/></joint>')


def _leg(leg: int, robot: RobotConfig, geom: LegGeometry, inertias: dict[str, Inertia]) -> list[str]:
    name = LEG_NAMES[leg]
    coxa, femur, tibia = (f"{name}_{part}" for part in LINKS_PER_LEG)
    lower, upper = geom.lower, geom.upper
    grey = '<material name="grey"><color rgba="0.45 0.45 0.5 1"/></material>'
    dark = '<material name="dark"><color rgba="0.15 0.15 0.18 1"/></material>'
    femur_box = (robot.femur_length, robot.femur_section[1], robot.femur_section[0])
    tibia_geometry = f'<cylinder radius="{robot.tibia_radius:.17g}" length="{robot.tibia_length:.17g}"/>'
    foot_geometry = f'<sphere radius="{robot.foot_radius:.17g}"/>'
    foot_xyz = (robot.tibia_length, 0.0, 0.0)
    return [
        _link(coxa, inertias["coxa"], [_geometry_block("visual", f'<box size="{_vec(robot.coxa_size)}"/>',
                                                       material=dark)], []),
        _link(femur, inertias["femur"],
              [_geometry_block("visual", f'<box size="{_vec(femur_box)}"/>', (robot.femur_length / 2, 0, 0),
                               material=grey)], []),
        _link(tibia, inertias["tibia"],
              [_geometry_block("visual", tibia_geometry, (robot.tibia_length / 2, 0, 0), (0, math.pi / 2, 0),
                               material=grey),
               _geometry_block("visual", foot_geometry, foot_xyz, material=dark)],
              [_geometry_block("collision", foot_geometry, foot_xyz)]),
        # Joint 1 about z_0i; the leg base O_0i sits at a01_i along the direction theta0_i (eq. 2).
        _joint(f"{name}_joint1", "body", coxa, geom.base_positions[leg], (0, 0, geom.base_angle[leg]),
               lower[0], upper[0], robot),
        # Joint 2: DH alpha_1 = 90 deg turns z onto the horizontal joint axis z_1i.
        _joint(f"{name}_joint2", coxa, femur, (0, 0, 0), (math.pi / 2, 0, 0), lower[1], upper[1], robot),
        _joint(f"{name}_joint3", femur, tibia, (robot.femur_length, 0, 0), (0, 0, 0), lower[2], upper[2], robot),
    ]


def build_urdf(robot: RobotConfig) -> str:
    geom = LegGeometry.from_config(robot)
    inertias = link_inertias(robot)
    body_visual = _geometry_block("visual", f'<box size="{_vec(robot.body_size)}"/>',
                                  material='<material name="body"><color rgba="0.2 0.45 0.8 1"/></material>')
    body_collision = _geometry_block("collision", f'<box size="{_vec(robot.body_size)}"/>')
    lines = ['<?xml version="1.0"?>', '<robot name="hexapod">',
             _link("body", inertias["body"], [body_visual], [body_collision])]
    for leg in range(6):
        lines.extend(_leg(leg, robot, geom, inertias))
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def joint_names() -> list[str]:
    """Names of the 18 joints in the order of the configuration vector q (eq. 1)."""
    return [f"{leg}_joint{j}" for leg in LEG_NAMES for j in (1, 2, 3)]


def foot_offset(robot: RobotConfig) -> np.ndarray:
    """The foot sphere centre in its tibia link frame."""
    return np.array([robot.tibia_length, 0.0, 0.0])
