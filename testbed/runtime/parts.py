"""Which parts a run is made of, and where each came from: what a recording stores so that the
run can be found again (spec, module, the module file's hash, the package and its version)."""

from __future__ import annotations

from estimators.registry import ESTIMATORS
from estimators.registry import NONE as NO_ESTIMATOR
from sensors.sensor import SENSORS
from testbed.control.controller import CONTROLLERS
from testbed.control.gait import GAITS
from testbed.world.terrain import TERRAINS


def part_sources(config) -> dict[str, dict]:
    """kind -> PluginSource.to_dict() of every part the config names (sensors: every registered
    one), for parts that are imported; a part not imported yet is described by its spec alone."""
    named = {"estimator": (ESTIMATORS, config.run.estimator), "controller": (CONTROLLERS, config.run.controller),
             "terrain": (TERRAINS, config.run.terrain), "gait": (GAITS, config.run.gait)}
    sources = {kind: registry.source(spec).to_dict() for kind, (registry, spec) in named.items()
               if not (kind == "estimator" and spec == NO_ESTIMATOR)}
    sources.update({f"sensor {name}": SENSORS.source(name).to_dict() for name in SENSORS.names()})
    return sources
