"""The robot's links as frames for /tf: each joint's child link in its parent link, read from the
URDF the run recorded (`codec.Encoder` publishes them with the body's pose).

A URDF joint places its child link at `origin` (xyz, then rpy as R = Rz(yaw) Ry(pitch) Rx(roll))
in the parent link, turned by the joint position about `axis` (URDF specification, <joint>):
parent_from_child = Origin * Rot(axis, q). Link frames carry the link names, so that a viewer
that loads the URDF (Foxglove's 3D panel, from /robot_description) draws each link in its frame.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from testbed.model import spatial
from testbed.model.robot import joint_names


@dataclass(frozen=True)
class Joint:
    name: str
    parent: str                     # parent link's name
    child: str                      # child link's name
    translation: tuple[float, float, float]      # m, the child's origin in the parent link
    origin: spatial.Quaternion      # parent_from_joint at q = 0 (x, y, z, w)
    axis: tuple[float, float, float]             # unit, in the joint frame


@dataclass(frozen=True)
class LinkTree:
    """The root link and the moving joints, in the order of the truth's joint positions."""
    root: str
    joints: tuple[Joint, ...]

    @classmethod
    def from_urdf(cls, urdf: str, order: Sequence[str] | None = None) -> "LinkTree":
        """The revolute and continuous joints of `urdf`, in `order` (joint names; default: the
        hexapod's, `testbed.model.robot.joint_names`)."""
        robot = ElementTree.fromstring(urdf)
        joints = {element.get("name"): _joint(element) for element in robot.iter("joint")
                  if element.get("type") in ("revolute", "continuous")}
        children = {joint.child for joint in joints.values()}
        root = next((link.get("name") for link in robot.iter("link") if link.get("name") not in children), None)
        if root is None:
            raise ValueError("the URDF has no root link")
        names = list(order) if order is not None else joint_names()
        missing = [name for name in names if name not in joints]
        if missing:
            raise ValueError(f"the URDF has no joint {', '.join(missing)}")
        return cls(root, tuple(joints[name] for name in names))

    def rotations(self, joint_positions: Sequence[float]) -> list[spatial.Quaternion]:
        """Each joint's parent_from_child rotation at these joint positions (rad)."""
        rotations = []
        for joint, q in zip(self.joints, joint_positions):
            ax, ay, az = joint.axis
            rotations.append(spatial.multiply(joint.origin, spatial.exp(ax * q, ay * q, az * q)))
        return rotations


def _joint(element: ElementTree.Element) -> Joint:
    origin = element.find("origin")
    xyz = _floats(origin.get("xyz") if origin is not None else None)
    roll, pitch, yaw = _floats(origin.get("rpy") if origin is not None else None)
    axis_element = element.find("axis")
    axis = np.array(_floats(axis_element.get("xyz") if axis_element is not None else "1 0 0"))
    axis = axis / np.linalg.norm(axis)
    return Joint(element.get("name"), element.find("parent").get("link"), element.find("child").get("link"),
                 xyz, spatial.quaternion_from_euler(roll, pitch, yaw), tuple(float(v) for v in axis))


def _floats(text: str | None) -> tuple[float, float, float]:
    x, y, z = (float(value) for value in (text or "0 0 0").split())
    return x, y, z
