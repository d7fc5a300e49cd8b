"""The controller interface: what runs on the robot's computer after the estimator.

Each control tick a controller gets the sensor samples stamped since the previous tick and the
estimator's latest estimate (None before the first, or with no estimator), never ground truth,
and answers the 18 joint position targets (rad, leg by leg: coxa, femur, tibia) or None to keep
the previous ones. The built-in controllers (`none`, `posture`) are the gait + posture + IK pilot.
"""

from __future__ import annotations

import abc
from typing import Any

import numpy as np

from estimators.base import Estimate
from sensors.samples import Sample
from testbed.model.errors import PluginFailure
from testbed.model.registry import Registry
from testbed.model.truth import NUM_JOINTS


class Controller(abc.ABC):
    """Subclass it and implement `tick`. A class method `from_config(config)` receives the run's
    `Config` when present; otherwise the class is built with no arguments."""

    def start(self, joint_positions: np.ndarray) -> None:
        """The joint positions (18,) the servos hold at t = 0, before the first tick."""

    @abc.abstractmethod
    def tick(self, t: float, samples: list[Sample], estimate: Estimate | None) -> np.ndarray | None:
        """Joint position targets (18,) in rad for the next physics steps, or None to keep the last."""

    def arrived(self) -> bool:
        """Whether the controller has reached where it was sent (the pilot: `gait.target`): with
        `gait.end_at_arrival` the run ends soon after. False by default."""
        return False

    def command_details(self) -> Any:
        """What the controller commanded besides the joints (the pilot: gait phase, swing, foot
        targets, twist) as a `testbed.control.command.Command`, or None."""
        return None


CONTROLLERS = Registry.of_subclasses("controller", "controllers", Controller)


def checked_targets(targets: Any, spec: str) -> np.ndarray:
    """A controller's answer as a finite float array (18,); anything else is a PluginFailure."""
    array = np.asarray(targets, dtype=float) if targets is not None else None
    if array is None or array.shape != (NUM_JOINTS,) or not np.all(np.isfinite(array)):
        shape = None if array is None else array.shape
        what = "non-finite targets" if shape == (NUM_JOINTS,) else f"shape {shape}"
        raise PluginFailure(f"controller '{spec}' returned {what}, expected {NUM_JOINTS} finite joint targets in rad")
    return array
