"""What the run loop hands to a recorder, tick by tick. The recorder sits beside the data flow:
it reads everything and feeds nothing back.

`datasets.recorder.McapRecorder` implements `Recorder`; `NullRecorder` records nothing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np

from sensors.samples import Sample
from testbed.control.command import Command
from testbed.world.contact import FootContacts
from testbed.model.truth import Truth

if TYPE_CHECKING:
    from estimators.base import Estimate
    from testbed.runtime.config import Config
    from testbed.world.terrain import Terrain



class Tick(NamedTuple):
    """Everything of one physics step."""
    truth: Truth
    truth_quaternion: np.ndarray         # (4,) world_from_body, scipy order x, y, z, w: what scoring uses
    contacts: FootContacts               # contact points, normals and forces, world
    support_polygon: np.ndarray          # (K, 2) world x, y of the stance feet's convex hull, counter-clockwise
    stability_margin: float              # m, centre-of-mass projection to the nearest hull edge (< 0 outside)
    samples: list[Sample]                # sensor samples stamped in (previous tick, this tick]
    estimates: list["Estimate"]          # estimates produced from those samples
    command: Command


class Recorder(Protocol):
    def start(self, config: "Config", urdf: str, terrain: "Terrain") -> None: ...

    def record(self, tick: Tick) -> None: ...

    def finish(self, metrics: dict, error: str | None) -> None:
        """Always called, also after an interrupt or a diverging simulation."""


class NullRecorder:
    def start(self, config, urdf, terrain) -> None:
        pass

    def record(self, tick: Tick) -> None:
        pass

    def finish(self, metrics: dict, error: str | None) -> None:
        pass
