"""Hexapod control and sensor-fusion testbed."""

_EXPORTS = {"Controller": "testbed.control.controller", "Terrain": "testbed.world.terrain"}


def __getattr__(name):
    import importlib
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'testbed' has no attribute {name!r}")
